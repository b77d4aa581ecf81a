"""The calibration result as the page downloads it: the report, the projection-uncertainty map
as a PNG, the camera file in one of its formats; and the small cache that keeps each until the
views or the solve change."""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path
from typing import Any, Generic, Literal, TypeVar

import cv2

from drovisio.calibration.report import build_report, uncertainty_image
from drovisio.calibration.session import CalibrationSession
from drovisio.camera import Camera
from drovisio.camera_file import save_camera

__all__ = ["CAMERA_SUFFIX", "KeyedCache", "camera_file_bytes", "report", "uncertainty_png"]

CameraFormat = Literal["opencv", "ros", "json"]
#: the camera file's name ending per format
CAMERA_SUFFIX: dict[str, str] = {"opencv": ".yaml", "ros": ".ros.yaml", "json": ".json"}

T = TypeVar("T")


class KeyedCache(Generic[T]):
    """One value and the key it was made for (session, generation, solve…); thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: tuple[tuple[Any, ...], T] | None = None

    def get(self, key: tuple[Any, ...]) -> T | None:
        with self._lock:
            if self._item is not None and self._item[0] == key:
                return self._item[1]
        return None

    def put(self, key: tuple[Any, ...], value: T) -> T:
        with self._lock:
            self._item = (key, value)
        return value

    def clear(self) -> None:
        with self._lock:
            self._item = None


def report(sess: CalibrationSession, session_id: str, result_seq: int) -> dict[str, Any]:
    """The report of the session's result (see :func:`build_report`), saying whether it is of
    the current views and which session and solve it is."""
    rep = build_report(sess)
    rep["current"] = sess.result_is_current
    rep["session_id"] = session_id
    rep["result_seq"] = result_seq
    return rep


def uncertainty_png(result: Any, threshold_px: float) -> bytes:
    """The projection-uncertainty map of a result as a PNG (``threshold_px``: the verdict's
    limit, pixels)."""
    img = uncertainty_image(result, threshold_px=threshold_px)
    _, buf = cv2.imencode(".png", img)
    return buf.tobytes()


def camera_file_bytes(camera: Camera, fmt: str) -> tuple[bytes, str] | None:
    """The camera file (bytes, name ending) in format ``fmt`` (opencv, ros or json); None for
    another format."""
    ext = CAMERA_SUFFIX.get(fmt)
    if ext is None:
        return None
    kind: CameraFormat = "opencv" if fmt == "opencv" else "ros" if fmt == "ros" else "json"
    with tempfile.TemporaryDirectory() as d:
        p = save_camera(camera, Path(d) / f"camera{ext}", fmt=kind)
        return p.read_bytes(), ext
