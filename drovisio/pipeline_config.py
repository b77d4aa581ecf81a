"""The positioning pipeline's configuration: one typed model for ``drovisio run``, ``drovisio
serve`` (the web tool's :class:`~webtool.settings.Settings` holds one) and the benchmarks.

Built from the command line at its edge only (:meth:`PipelineConfig.from_args`); everything
below (:func:`drovisio.startup.build_pipeline`, the start-up check) reads the typed fields.
File names are kept as given, so that a message quotes them as the user typed them.
"""

from __future__ import annotations

import argparse
from typing import Literal

from pydantic import BaseModel, Field

__all__ = ["PipelineConfig"]

Pace = Literal["realtime", "max"]


class PipelineConfig(BaseModel):
    """What the pipeline runs on and where its results go (the options ``run`` and ``serve``
    share). Defaults are the command line's."""

    source: str | None = None
    """Camera index (``0``), video file, folder of images (name order) or stream URL. None:
    none given (the web tool then runs on its sample session; ``run`` requires one)."""
    camera: str | None = None
    """Camera file (OpenCV FileStorage YAML/XML/JSON or ROS camera_info YAML); None: none
    given (the web tool then uses the sample's or the calibrated camera)."""
    layouts: list[str] = []
    """Marker layout files; empty: none given (the web tool then loads the shipped ones)."""
    mount: str | None = None
    """Camera mount file, for poses in the drone's FRD body frame; None: camera frame only."""
    sinks: list[str] = []
    """Sink specs (``jsonl:-``, ``udp://HOST:PORT``, ``mavlink:CONNECTION``, ``ws://HOST:PORT``,
    ``zenoh:...``); empty: the caller's default (``run``: ``jsonl:-``; the web tool: none)."""
    target: str = "nearest"
    """The brick sent to the flight controller: ``nearest``, ``LAYOUT``, ``LAYOUT:INSTANCE``,
    ``track:N`` or ``none``."""
    autopilot: Literal["ardupilot", "px4"] = "ardupilot"
    """LANDING_TARGET flavour of ``mavlink:`` sinks: ArduPilot (BODY_FRD + distance) or PX4
    (LOCAL_NED)."""
    record: str | None = None
    """Record frames and results into this folder, or into this ``.mcap`` file; None: no
    recording."""
    record_images: Literal["jpeg", "png"] = "jpeg"
    """Image encoding of an ``.mcap`` recording (jpeg quality 95, or lossless png)."""
    drone_id: str | None = None
    """This drone's name on a site with several: ROS 2 topics under ``/drovisio/ID``."""
    send_held_targets: bool = False
    """Also send the flight controller a target not seen in the current frame (its last
    measurement)."""
    max_age: float = Field(default=0.5, gt=0)
    """Drop a brick not seen for this long, seconds."""
    pace: Pace = "realtime"
    """Files and recordings: at their own frame rate like a camera (``realtime``) or as fast as
    possible (``max``)."""

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> PipelineConfig:
        """The configuration a parsed ``run`` or ``serve`` command line gives (an option a
        command does not have keeps its default)."""
        given = {"source": getattr(args, "source", None),
                 "camera": getattr(args, "camera", None),
                 "layouts": [str(x) for x in getattr(args, "layout", None) or []],
                 "mount": getattr(args, "mount", None) or None,
                 "sinks": list(getattr(args, "sink", None) or []),
                 "target": getattr(args, "target", None) or "nearest",
                 "autopilot": getattr(args, "autopilot", None) or "ardupilot",
                 "record": getattr(args, "record", None) or None,
                 "record_images": getattr(args, "record_images", None) or "jpeg",
                 "drone_id": getattr(args, "drone_id", None),
                 "send_held_targets": bool(getattr(args, "send_held_targets", False)),
                 "max_age": getattr(args, "max_age", 0.5),
                 "pace": getattr(args, "pace", None) or "realtime"}
        return cls(**{k: (str(v) if k in _PATHS and v is not None else v)
                      for k, v in given.items()})


_PATHS = ("source", "camera", "mount", "record")
