"""SOURCE strings (the ``--source`` of ``drovisio run``) to readers: a camera index (``0``:
V4L2), a video file, a folder of images (name order), a recording folder (made by
``--record``; has ``recording.json``), an MCAP recording, or a stream URL (``rtsp://``,
``http://``, ``udp://``, ``tcp://`` …, through FFmpeg)."""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import urlsplit

from drovisio.bounds import MAX_CAMERA_INDEX, parse_whole
from drovisio.errors import InputError, one_line
from drovisio.sources.camera import CameraReader
from drovisio.sources.folders import ImageFolderReader, RecordingReader
from drovisio.sources.frame_source import FrameSource
from drovisio.sources.reader import Pace, Reader
from drovisio.sources.stream import StreamReader
from drovisio.sources.video import VideoFileReader
from drovisio.textfile import missing_reason

__all__ = ["open_source", "reader_for"]


def _is_url(s: str) -> bool:
    return "://" in s and not s.startswith("file://")


def _check_url(url: str) -> None:
    """A stream URL that can never connect (no host, a port that is no port, broken
    brackets) is refused now; a sound one is retried for as long as it is down.

    Raises:
        InputError: naming ``--source`` and what is wrong.
    """
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - parsing the port is what may fail
    except ValueError as e:
        raise InputError(f"{one_line(url, 200)}: --source: not a usable URL ({e}); give "
                         "e.g. rtsp://HOST:554/stream or http://HOST:8080/video") from None
    if parts.scheme.lower() in ("http", "https", "rtsp", "rtsps", "rtmp", "tcp") \
            and not parts.hostname:
        raise InputError(f"{one_line(url, 200)}: --source: the URL names no host; give "
                         f"e.g. {parts.scheme}://HOST:PORT/...")


def _camera_index(s: str) -> int | None:
    """The camera index ``s`` names (``N`` or ``/dev/videoN``), None when it names none.

    Raises:
        InputError: a number that is no camera index.
    """
    digits = s.removeprefix("/dev/video")
    if not digits.isdigit():
        return None
    try:
        return parse_whole(digits, 0, MAX_CAMERA_INDEX)
    except ValueError:
        shown = one_line(s, 40)
        raise InputError(f"{shown}: --source: not a camera index (0 to {MAX_CAMERA_INDEX}, "
                         f"for /dev/videoN); a file or folder of that name is ./{shown}") \
            from None


def reader_for(source: str, loop: bool = False, folder_fps: float = 10.0) -> Reader:
    """The reader of a SOURCE string (see the module doc).

    Raises:
        InputError: a file or folder that does not exist, or that is not a video, an image
            folder or a recording (cameras and URLs are not checked: they may come later).
    """
    s = str(source).strip()
    cam = _camera_index(s)
    if cam is not None:
        reader = CameraReader(cam)
        if s.isdigit() and os.path.lexists(s):  # said in every message that names the source
            reader.label += f" (not the file or folder {s} here: that is ./{s})"
        return reader
    if _is_url(s):
        _check_url(s)
        return StreamReader(s)
    s = s.removeprefix("file://")
    p = Path(s)
    if p.is_dir():
        if (p / "recording.json").is_file():
            return RecordingReader(p, loop=loop)
        return ImageFolderReader(p, fps=folder_fps, loop=loop)
    why = missing_reason(p)
    if why and os.path.lexists(p):    # a link that leads nowhere: said as one
        raise InputError(f"{s}: --source: {why}")
    if why:
        raise InputError(f"{s}: --source: no such file or folder (give a camera index such "
                         "as 0, a video file, a folder of images or a stream URL)")
    if not p.is_file():
        raise InputError(f"{s}: --source: not a regular file (a pipe or a device); give a "
                         "camera index (0) for a camera")
    if p.suffix.lower() == ".mcap":   # an MCAP recording (drovisio run --record FILE.mcap)
        from drovisio.ros.mcap_source import McapReader  # deferred: it loads OpenCV

        return McapReader(p, loop=loop)
    return VideoFileReader(p, loop=loop)




def open_source(source: str, pace: Pace = "realtime", loop: bool = False) -> FrameSource:
    """A started :class:`FrameSource` for a SOURCE string."""
    return FrameSource(reader_for(source, loop=loop), pace=pace).start()
