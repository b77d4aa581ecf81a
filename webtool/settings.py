"""Settings of one web-tool instance (what `drovisio serve` was asked to do)."""

from __future__ import annotations

import ipaddress
import os
import secrets
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, model_validator

from drovisio.pipeline_config import PipelineConfig
from drovisio.resources import sample_sessions_dir, user_data_dir

DEFAULT_SAMPLE_SESSION = sample_sessions_dir()


def is_loopback(host: str | None) -> bool:
    """True for 127.0.0.0/8, ::1 (also IPv4-mapped) and "localhost"; False for anything else."""
    if not host:
        return False
    host = host.strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        return False
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return addr.is_loopback


def new_token() -> str:
    return secrets.token_urlsafe(16)


_PIPELINE_FIELDS = frozenset(PipelineConfig.model_fields)
"""The options of ``drovisio run`` a server takes too, given flat (``Settings(sinks=[...])``)
or as ``pipeline``."""


def _as_text(value: object) -> object:
    """A path as the configuration keeps it (text); anything else as it is."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple)):
        return [os.fspath(v) if isinstance(v, os.PathLike) else v for v in value]
    return value


def _path(value: str | None) -> Path | None:
    return None if value is None else Path(value)


class Settings(BaseModel):
    """What one server was asked to do. The pipeline's options (``source``, ``camera``,
    ``layouts``, ``mount``, ``sinks``, ...) may be given flat, as ``drovisio serve`` passes
    them; they live in :attr:`pipeline`, and read back as the server's own (paths as
    :class:`~pathlib.Path`)."""

    host: str = "127.0.0.1"
    port: int = 8080
    pipeline: PipelineConfig = Field(default_factory=PipelineConfig)
    """The pipeline of the live page, as `drovisio run` takes it (one process on the drone:
    what the page shows is what the flight controller is sent). No source: the sample
    session; empty layouts: the shipped ones (the sample session's with no source); with
    sinks, the pipeline runs from the start."""
    sample_session: Path = DEFAULT_SAMPLE_SESSION
    # The user's data folder of this server (`drovisio serve --data DIR`): calibration,
    # mount, saved layouts and study reports live in its sub-folders unless one of the
    # *_dir settings below names another. None: drovisio.resources.user_data_dir().
    data_dir: Path | None = None
    # Calibration page (webtool.calibration_service). Sessions are saved under
    # calibration_dir/<session-id>/ (None: $XDG_DATA_HOME or ~/.local/share, then
    # drovisio/calibration); a new session uses this board unless the page asks for another.
    calibration_dir: Path | None = None
    calibration_board: str = "chessboard:9x6"
    calibration_square_m: float = 0.025
    # With no source, the sample calibration views play as if live, this many seconds each.
    sample_seconds_per_view: float = 1.5
    # Marker designer (webtool.designer_scene): designs are saved into this folder (None: the
    # data folder's layouts/; the shipped marker_layouts/ are read-only); mesh uploads larger
    # than this are refused before reading.
    designer_layouts_dir: Path | None = None
    designer_max_upload_mb: float = 50.0
    # Camera mount page (webtool.mount_service): with no --mount, the mount set there is saved
    # as mount_dir/mount.json (None: $XDG_DATA_HOME or ~/.local/share, then drovisio/mount).
    mount_dir: Path | None = None
    # Study page (webtool.study_service): the reports of `drovisio study run --out` kept here,
    # and those started from the page (None: $XDG_DATA_HOME or ~/.local/share, then
    # drovisio/study).
    study_dir: Path | None = None
    # Replay panel of the live page (webtool.replay_service): the folder of simulated mission
    # recordings (`drovisio mission simulate ... --record DIR`) it lists; None: no replay.
    replay_dir: Path | None = None
    # The ground station (`drovisio station`): Zenoh endpoints where drones are heard
    # (listen: they connect here; connect: a router or drones that listen) and the ROS domain
    # id; none: this web tool is no station and its Fleet page says so.
    station_listen: list[str] = []
    station_connect: list[str] = []
    station_domain: int = Field(default=0, ge=0, le=232)
    # Most WebSockets open at once, the live image streams and the 3D views together (each
    # holds buffers and a share of the bandwidth); one more is refused (503) until one closes.
    max_sockets: int = Field(default=32, ge=1, le=1000)
    # Access token. None means "no token needed", which is only allowed on a loopback host:
    # binding anywhere else generates one (see `token_required`).
    token: str | None = None
    # Read-only viewer token (webtool.access): watches pages and streams, cannot change
    # anything (writes answer 403). Made together with `token` when token access is on.
    viewer_token: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _pipeline_options(cls, data: Any) -> Any:
        """The pipeline's options given flat (``source=``, ``sinks=``, ...) go into
        ``pipeline``."""
        if not isinstance(data, dict) or not _PIPELINE_FIELDS & data.keys():
            return data
        data = dict(data)
        given = data.pop("pipeline", None)
        if isinstance(given, PipelineConfig):
            given = given.model_dump()
        options = dict(given or {})
        for name in _PIPELINE_FIELDS & data.keys():
            options[name] = _as_text(data.pop(name))
        data["pipeline"] = options
        return data

    @model_validator(mode="after")
    def _token_when_exposed(self) -> Settings:
        if self.token is None and not is_loopback(self.host):
            self.token = new_token()
        if self.token is not None and self.viewer_token is None:
            self.viewer_token = new_token()
        if self.viewer_token is not None and self.viewer_token == self.token:
            raise ValueError("the viewer token must differ from the access token")
        return self

    def user_folder(self, area: str) -> Path:
        """Where this server keeps one area's user data (``calibration``, ``mount``,
        ``layouts``, ``study``): the area's own setting, else ``data_dir/area``, else the
        user's data folder's."""
        own = {"calibration": self.calibration_dir, "mount": self.mount_dir,
               "layouts": self.designer_layouts_dir, "study": self.study_dir}[area]
        if own is not None:
            return Path(own)
        if self.data_dir is not None:
            return Path(self.data_dir) / area
        return user_data_dir(area)

    # The pipeline's options read (and, for the camera and the mount the pages set, written)
    # as the server's own, as paths.
    @property
    def source(self) -> str | None:
        return self.pipeline.source

    @property
    def camera(self) -> Path | None:
        return _path(self.pipeline.camera)

    @camera.setter
    def camera(self, value: str | os.PathLike | None) -> None:
        self.pipeline.camera = None if value is None else os.fspath(value)

    @property
    def layouts(self) -> list[Path]:
        return [Path(x) for x in self.pipeline.layouts]

    @property
    def mount(self) -> Path | None:
        return _path(self.pipeline.mount)

    @mount.setter
    def mount(self, value: str | os.PathLike | None) -> None:
        self.pipeline.mount = None if value is None else os.fspath(value)

    @property
    def sinks(self) -> list[str]:
        return self.pipeline.sinks

    @property
    def record(self) -> Path | None:
        return _path(self.pipeline.record)

    @property
    def record_images(self) -> str:
        return self.pipeline.record_images

    @property
    def drone_id(self) -> str | None:
        return self.pipeline.drone_id

    @property
    def is_station(self) -> bool:
        return bool(self.station_listen or self.station_connect)

    @property
    def flying(self) -> bool:
        """Sinks are given: the pipeline feeds something (the flight controller) and runs
        whether anyone watches or not."""
        return bool(self.sinks)

    @property
    def token_required(self) -> bool:
        return self.token is not None

    @property
    def uses_sample_session(self) -> bool:
        return self.source is None

    @property
    def source_label(self) -> str:
        """The source as shown to people and in /api/health."""
        if self.source is None:
            return f"sample session: {self.sample_session}"
        return self.source
