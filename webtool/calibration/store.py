"""The calibration sessions on disk: one folder per session under the calibration folder.

Layout of ``calibration_dir``::

    current                  the id of the session last open (resumed on start)
    in-use.json              the camera file chosen with "Use this calibration"
    <session-id>/
        session.json         the session's state (board, image size, detections, page
                             settings), written after the images it names
        images/NAME          every kept view's image (camera captures and uploads)
        deleted/NAME         views deleted on the page (moved, never erased)
        camera.yaml          the result in use (and camera.ros.yaml)

Every file is written through a temporary file renamed over the target.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import re
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from drovisio.calibration.report import _clean
from drovisio.calibration.session import CalibrationSession
from drovisio.camera_file import load_camera
from drovisio.fileio import atomic_write_bytes as _atomic_write_bytes
from drovisio.images import IMAGE_SUFFIXES, ImageError, read_image
from drovisio.resources import user_data_dir
from drovisio.textfile import parse_json, read_text

__all__ = [
    "IN_USE_FILE",
    "SESSION_SCHEMA",
    "atomic_write_bytes",
    "calibration_root",
    "camera_in_use",
    "default_calibration_dir",
    "next_capture_number",
    "read_session_file",
    "recover_orphans",
    "remember_in_use",
    "safe_name",
    "session_candidates",
    "unique_upload_name",
    "write_session_file",
]

log = logging.getLogger(__name__)

SESSION_SCHEMA = "drovisio/calibration-web-session@1"
IN_USE_FILE = "in-use.json"


def default_calibration_dir() -> Path:
    return user_data_dir("calibration")


def calibration_root(settings: Any) -> Path:
    """The folder of this server's calibration sessions."""
    if hasattr(settings, "user_folder"):
        return Path(settings.user_folder("calibration"))
    return Path(settings.calibration_dir) if getattr(settings, "calibration_dir", None) \
        else default_calibration_dir()


def camera_in_use(settings: Any) -> Path | None:
    """The camera file last chosen with "Use this calibration" (``calibration_dir/in-use.json``),
    if it still loads; None otherwise (a broken choice is logged and ignored)."""
    f = calibration_root(settings) / IN_USE_FILE
    if not f.is_file():
        return None
    try:
        path = Path(json.loads(f.read_text(encoding="utf-8"))["camera_file"])
        load_camera(path)
    except Exception as e:  # noqa: BLE001 - any failure: keep the default camera
        log.warning("calibration in use (%s) not restored: %s", f, e)
        return None
    return path


def remember_in_use(root: Path, camera_file: Path, session_id: str) -> None:
    """Remember the camera file in use for the next start of the web tool."""
    atomic_write_bytes(root / IN_USE_FILE, json.dumps(
        {"camera_file": str(camera_file), "session": session_id, "at": time.time()},
        indent=2).encode())


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:mod:`drovisio.fileio`), making its folder."""
    _atomic_write_bytes(path, data, make_parents=True)


def safe_name(name: str) -> str:
    """A plain file name (no folders, no odd characters, at most 80 characters)."""
    base = re.split(r"[\\/]", name or "")[-1]
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", base).strip("._") or "image"
    return base[:80]


def session_candidates(root: Path) -> list[str]:
    """Session ids to try resuming, best first: the current one, then the newest saved."""
    candidates = []
    try:
        candidates.append((root / "current").read_text(encoding="utf-8").strip())
    except OSError:
        pass
    others = sorted((p for p in root.iterdir() if (p / "session.json").is_file()),
                    key=lambda p: (p / "session.json").stat().st_mtime, reverse=True)
    return candidates + [p.name for p in others]


def read_session_file(path: Path) -> dict[str, Any]:
    """The saved state of a session (``session.json``); raises ValueError (or OSError) when it
    is not one."""
    data = parse_json(read_text(path, "calibration session"), str(path))
    if not isinstance(data, dict):
        raise ValueError("not a session")
    return data


def check_view_names(session: CalibrationSession) -> None:
    """The image names inside session.json name files in this session's folder only."""
    for name in [v.name for v in session.views]:
        if not isinstance(name, str) or safe_name(name) != name:
            raise ValueError(f"images: {name!r} is not a plain file name")


def set_aside_broken(path: Path) -> None:
    """Keep a session file that could not be read, for inspection (the images stay)."""
    try:
        os.replace(path, path.parent / f"session.json.broken-{int(time.time())}")
    except OSError:
        pass


def write_session_file(folder: Path, data: dict[str, Any]) -> None:
    """Write ``session.json`` atomically (after the images it names)."""
    atomic_write_bytes(folder / "session.json", json.dumps(_clean(data), indent=1).encode())


def next_capture_number(folder: Path) -> int:
    """The number of the next ``capture-NNNN`` image (after those kept and deleted)."""
    nums = [0]
    for d in (folder / "images", folder / "deleted"):
        if d.is_dir():
            nums += [int(m.group(1)) for f in d.iterdir()
                     if (m := re.match(r"capture-(\d{1,9})(?!\d)", f.name))]
    return max(nums) + 1


def recover_orphans(session: CalibrationSession, images_dir: Path) -> int:
    """Add back the images written just before a crash, whose view never reached
    session.json; returns how many were kept."""
    if not images_dir.is_dir():
        return 0
    known: set[Any] = {v.name for v in session.views}
    known |= {r.get("file") for r in session.rejected}
    kept = 0
    for f in sorted(images_dir.iterdir()):
        if f.name in known or f.name.startswith(".") or \
                f.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        try:   # bounded: a FIFO or a 20 GB file named like an image is not read
            img = read_image(f)[0]
        except ImageError as e:
            session.add_rejected(f.name, str(e))
            continue
        if session.add_image(img, f.name).kept:
            kept += 1
    return kept


def _numbered(name: str) -> Iterator[str]:
    """``name``, then ``STEM-2.EXT``, ``STEM-3.EXT``, … (the first free one is taken)."""
    stem, suf = os.path.splitext(name)
    yield name
    for k in itertools.count(2):
        yield f"{stem}-{k}{suf}"


def move_to_deleted(folder: Path, name: str) -> Path | None:
    """Move a deleted view's image to ``deleted/`` (never erased: numbered when an image of
    that name was deleted before). Returns where it went (None: there was no image)."""
    src = folder / "images" / name
    if not src.exists():
        return None
    bin_ = folder / "deleted"
    bin_.mkdir(exist_ok=True)
    for cand in _numbered(name):
        dest = bin_ / cand
        try:   # a hard link is made only where no file is: nothing earlier is replaced
            os.link(src, dest)
        except FileExistsError:
            continue
        except OSError:   # no hard links on this drive: checked, under the caller's lock
            if dest.exists():
                continue
            os.replace(src, dest)
            return dest
        os.unlink(src)
        return dest
    return None   # not reached: the numbering never ends


def unique_upload_name(label: str, taken: Iterable[str], images_dir: Path) -> str:
    """``upload-NAME``, numbered when a view or a file has that name already."""
    names = set(taken)
    return next(c for c in _numbered("upload-" + safe_name(label))
                if c not in names and not (images_dir / c).exists())
