"""The Study page's service: the study reports of the data folder, and a study of the shipped
recorded-style protocol started from the page, in the background, with its progress.

Reports live in ``study_dir/<name>/`` (``report.html``, ``summary.json``, ``frames.jsonl``,
the figures), as ``drovisio study run --out`` writes them. Closing the service cancels the
study in progress and waits for it to end (no report is written for it).
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

from drovisio._threads import join_thread
from drovisio.errors import InputError, one_line
from drovisio.resources import sample_sessions_dir
from drovisio.study.protocol import load_protocol
from drovisio.study.report import write_report
from drovisio.study.run import StudyCancelled, run_study
from drovisio.textfile import parse_json, read_text
from webtool.errors import Conflict, NotFound

__all__ = ["StudyService"]

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,120}$")
MAX_ENTRIES = 2000
"""Most folder entries looked at for one listing (a folder of a million entries is not a
study folder)."""


def read_summary(path: Path) -> dict:
    """The fields the listing shows from a report's ``summary.json``, read through the
    bounded reader and checked.

    Raises:
        InputError: one line naming the file and the field.
    """
    s = parse_json(read_text(path, "study summary"), str(path))
    if not isinstance(s, dict):
        raise InputError(f"{path}: not a study summary (a JSON object)")
    protocol = s.get("protocol")
    frames = s.get("frames")
    seconds = s.get("seconds")
    skipped = s.get("skipped") or []
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int)
                               or frames < 0):
        raise InputError(f"{path}: frames: give a whole number, 0 or more")
    if seconds is not None and (isinstance(seconds, bool)
                                or not isinstance(seconds, (int, float)) or seconds < 0):
        raise InputError(f"{path}: seconds: give a number of seconds, 0 or more")
    if not isinstance(skipped, list):
        raise InputError(f"{path}: skipped: give a list")
    return {"protocol": None if protocol is None else one_line(protocol, 200),
            "frames": frames, "seconds": seconds, "skipped": len(skipped)}


class StudyService:
    """See the module doc.

    Args:
        settings: The web tool's settings (``study_dir``).
    """

    def __init__(self, settings) -> None:
        self.settings = settings
        self.folder = settings.user_folder("study")
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self.progress = {"running": False, "fraction": 0.0, "message": "", "error": None,
                         "report": None, "cancelled": False}

    def reports(self) -> list[dict]:
        """The reports in the folder, newest first."""
        return self.listing()["reports"]

    def listing(self) -> dict:
        """``{"reports": [...] newest first, "skipped": [{"name", "error"}]}``: every entry of
        the folder read on its own through the summary's checks (:func:`read_summary`); a bad
        one is skipped and named, never the whole listing lost."""
        out: list[dict] = []
        skipped: list[dict] = []
        try:
            entries = sorted(self.folder.iterdir()) if self.folder.is_dir() else []
        except OSError as e:
            return {"reports": [], "skipped": [{"name": str(self.folder),
                                                "error": one_line(e, 200)}]}
        for d in entries[:MAX_ENTRIES]:
            try:
                if not d.is_dir() or not (d / "report.html").is_file():
                    continue
                out.append({"name": d.name, **read_summary(d / "summary.json"),
                            "written": (d / "summary.json").stat().st_mtime})
            except (OSError, ValueError) as e:
                skipped.append({"name": one_line(d.name, 120), "error": one_line(e, 300)})
        return {"reports": sorted(out, key=lambda r: -r["written"]), "skipped": skipped}

    def report_file(self, name: str, file: str) -> Path:
        if not _NAME.match(name) or not re.match(r"^(report\.html|fig-6\.\d+\.png)$", file):
            raise NotFound("no such report")
        f = self.folder / name / file
        if not f.is_file():
            raise NotFound("no such report")
        return f

    def start(self) -> dict:
        """Run the shipped recorded-style protocol into a new report folder."""
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise Conflict("a study is already running: wait for it to finish")
            name = time.strftime("%Y%m%d-%H%M%S") + "-sample"
            self.progress = {"running": True, "fraction": 0.0, "message": "starting",
                             "error": None, "report": None, "cancelled": False, "name": name}
            self._cancel = threading.Event()
            self._thread = threading.Thread(target=self._run, args=(name, self._cancel),
                                            daemon=True, name="study")
            self._thread.start()
            return dict(self.progress)

    def _run(self, name: str, cancel: threading.Event) -> None:
        def say(frac: float, msg: str) -> None:
            self.progress.update(fraction=round(0.95 * frac, 3), message=msg)

        try:
            path = sample_sessions_dir() / "study" / "protocol.yaml"
            protocol = load_protocol(path)
            res = run_study(protocol, path.parent, memory_seconds=2.0, speed_bricks=(1, 5),
                            speed_frames=1, progress=say, landing_runs=3, cancel=cancel)
            out = self.folder / name
            write_report(res, out, f"drovisio study run --protocol {path} --out {out}",
                         path.read_text(encoding="utf-8"))
            self.progress.update(fraction=1.0, message="done", report=name)
        except StudyCancelled:
            self.progress.update(cancelled=True, message="cancelled: no report")
        except Exception as e:  # noqa: BLE001 - shown on the page, in one line
            self.progress.update(error=f"{type(e).__name__}: {e}")
        finally:
            self.progress["running"] = False

    def close(self) -> None:
        """Cancel the study in progress and wait for its thread to end: it renders and
        detects in native code (numba, OpenCV), and a thread left there while the
        interpreter exits aborts the process ("terminate called without an active
        exception"). The bound only turns a hang into a message."""
        with self._lock:
            th, cancel = self._thread, self._cancel
        if th is None:
            return
        cancel.set()
        join_thread(th, "running a study")
