"""Replay of a simulated mission recording (:mod:`drovisio.mission.record`) in the live page.

:class:`ReplayService` lists the recordings in ``Settings.replay_dir`` (each a folder with a
``manifest.json``), loads one and plays it: the playback time ``t`` is read off the clock
(``speed`` times real time, :class:`Playback`), and a server-side thread draws its latest
instant, at ~15 Hz, in the replay's own viser scene (:class:`webtool.replay.scene.ReplayScene`,
served through the app at ``/replay/3d/``). Only recordings inside the recordings folder can
be loaded.
"""

from __future__ import annotations

import bisect
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drovisio._threads import join_thread
from drovisio.errors import InputError, one_line
from drovisio.layout import shipped_layout_file
from drovisio.mission.record import load_manifest, load_recording
from drovisio.textfile import path_text_problem
from webtool.errors import BadInput, Conflict, Forbidden, NotFound
from webtool.replay.scene import ReplayScene

__all__ = ["Playback", "ReplayService", "layouts_note"]

log = logging.getLogger(__name__)
SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def _text(v: object) -> str | None:
    """A manifest's text field as text (a number or object there is shown, never trusted)."""
    return None if v is None else one_line(v, 120)


def _count(v: object) -> int:
    return len(v) if isinstance(v, list) else 0


_EVENT_WORDS = {
    "grabbed": "brick {b} grabbed",
    "released": "brick {b} released",
    "acquired": "brick {b} seen ({frames} frames)",
    "aligned": "aligned over {b}",
    "contact": "contact with {b}",
    "blind": "blind descent onto {b}",
    "transition": "{source} → {target} ({trigger})",
}
"""How each kind of tick event reads; a kind not listed reads as its fields."""


def _describe(e: dict) -> str:
    """An event of a tick in plain words (its fields as the recording has them)."""
    k = e.get("kind")
    fields = {a: e.get(a) for a in ("source", "target", "trigger", "frames")}
    if k == "placed":
        off = e.get("error_m", 0)
        cm = f"{float(off) * 100:.1f} cm off" if isinstance(off, (int, float)) else f"{off} off"
        return f"brick {e.get('brick')} placed ({cm})"
    if isinstance(k, str) and k in _EVENT_WORDS:
        return _EVENT_WORDS[k].format(b=e.get("brick"), **fields)
    rest = ", ".join(f"{a}={v}" for a, v in e.items() if a not in ("t", "kind"))
    return f"{k}" + (f": {rest}" if rest else "")


def layouts_note(manifest: dict, where: str) -> str | None:
    """Why bricks of a recording are drawn as boxes, in one line naming the manifest
    (``where``) and the field: the 3D view reads only shipped layouts (a recording is outside
    input: its layout names never reach a path); None when every brick's layout is one."""
    bricks = manifest.get("bricks")
    first: str | None = None
    seen, bad = set(), 0
    for i, b in enumerate(bricks if isinstance(bricks, list) else []):
        name = b.get("layout") if isinstance(b, dict) else None
        key = name if isinstance(name, str) else type(name).__name__
        if key in seen:
            continue
        seen.add(key)
        try:
            shipped_layout_file(name)
        except InputError as e:
            bad += 1
            first = first or f"{where}: bricks[{i}].layout: {e}"
    if first is None:
        return None
    more = f"; {bad - 1} more such name(s)" if bad > 1 else ""
    return f"{first}; the 3D view draws these bricks as boxes{more}"


# ------------------------------------------------------------------------------------------
# Playback
# ------------------------------------------------------------------------------------------


class Playback:
    """One loaded recording and its clock (thread-safe; times in recording seconds).

    While playing, the time is read off ``clock`` (monotonic seconds): ``t = t0 + speed ×
    (clock() − w0)``, where ``t0`` and ``w0`` are the time and the clock's reading when it was
    last set (play, seek, speed). Nothing has to step it, so a slow or blocked draw of the
    scene never holds the time back.
    """

    def __init__(self, path: Path, manifest: dict, ticks: list[dict],
                 clock: Callable[[], float] = time.monotonic):
        if not ticks:
            raise BadInput(f"{path}: the recording has no ticks")
        self.path = path
        self.manifest = manifest
        self.ticks = ticks
        self.times = [float(tk["t"]) for tk in ticks]
        self.duration = max(float(manifest.get("duration_s") or self.times[-1]), self.times[0])
        self.events = [e for tk in ticks for e in tk.get("events", [])]
        self._ends = list(itertools.accumulate(len(tk.get("events", [])) for tk in ticks))
        self.note = layouts_note(manifest, str(path / "manifest.json"))
        self._clock = clock
        self._lock = threading.Lock()
        self._t0 = self.times[0]
        self._w0 = clock()
        self.playing = False
        self.speed = 1.0

    def _at(self, w: float) -> float:
        """The time at the clock's reading ``w``; reaching the end stops there (under the
        lock)."""
        if not self.playing:
            return self._t0
        t = self._t0 + self.speed * (w - self._w0)
        if t >= self.duration:
            self._t0, self._w0, self.playing = self.duration, w, False
            return self.duration
        return t

    def now(self) -> tuple[float, bool, float]:
        """(t, playing, speed), read together."""
        with self._lock:
            t = self._at(self._clock())
            return t, self.playing, self.speed

    @property
    def t(self) -> float:
        return self.now()[0]

    def play(self) -> None:
        """Play on (from the start when at the end)."""
        with self._lock:
            w = self._clock()
            t = self._at(w)
            self._t0 = self.times[0] if t >= self.duration else t
            self._w0, self.playing = w, True

    def pause(self) -> None:
        with self._lock:
            w = self._clock()
            self._t0, self._w0 = self._at(w), w
            self.playing = False

    def seek(self, t: float) -> None:
        with self._lock:
            w = self._clock()
            self._at(w)
            self._t0, self._w0 = min(max(float(t), 0.0), self.duration), w

    def set_speed(self, x: float) -> None:
        with self._lock:
            w = self._clock()
            self._t0, self._w0 = self._at(w), w
            self.speed = float(x)

    def index(self, t: float | None = None) -> int:
        t = self.t if t is None else t
        return max(0, bisect.bisect_right(self.times, t + 1e-9) - 1)

    def tick(self) -> dict:
        return self.ticks[self.index()]

    def events_so_far(self, limit: int | None = None, i: int | None = None) -> list[dict]:
        """The events up to tick ``i`` (default: now), the last ``limit`` of them."""
        out = self.events[: self._ends[self.index() if i is None else i]]
        return out if limit is None else out[-limit:]

    def placed(self, i: int | None = None) -> list[str]:
        return sorted({str(e.get("brick")) for e in self.events_so_far(i=i)
                       if e.get("kind") == "placed"})


class ReplayService:
    """The app's replay: a folder of recordings, the loaded one, its playback thread."""

    def __init__(self, settings, hz: float = 15.0,
                 clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.period = 1.0 / hz
        self.clock = clock
        self.pb: Playback | None = None
        self.scene: ReplayScene | None = None
        # the loaded recording and the scene, swapped under it; never held across a draw, so
        # the state and the controls never wait on the 3D view
        self._lock = threading.RLock()
        # one load or scene start at a time (these draw)
        self._setup = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    # --------------------------------------------------------------- recordings
    def folder(self) -> Path:
        d = getattr(self.settings, "replay_dir", None)
        if d is None:
            raise NotFound("no recordings folder is configured (replay_dir; "
                              "`drovisio serve --replay-dir DIR`)")
        d = Path(d)
        if not d.is_dir():
            raise NotFound(f"the recordings folder {d} does not exist")
        return d

    def runs(self) -> list[dict]:
        d = self.folder()
        out = []
        for m in sorted(d.glob("*/manifest.json")) + sorted(d.glob("manifest.json")):
            item: dict[str, Any] = {"name": m.parent.name if m.parent != d else ".",
                                    "path": str(m.parent)}
            # entry by entry through the loader's own checks: a bad one is named, not fatal
            try:
                js = load_manifest(m.parent)
                bricks = js.get("bricks", [])
                item.update(scenario=_text(js.get("scenario")),
                            duration_s=js.get("duration_s"), outcome=_text(js.get("outcome")),
                            bricks=len(bricks) if isinstance(bricks, list) else 0, ok=True)
            except (OSError, ValueError) as e:
                item.update(ok=False, error=one_line(e, 300))
            out.append(item)
        return out

    def _resolve(self, name: str | None, path: str | None) -> Path:
        d = self.folder()
        for field, text in (("path", path), ("name", name)):
            problem = path_text_problem(text) if text else None
            if problem:
                raise BadInput(f"{field}: the {field} {problem}")
        if path:
            p = Path(path)
            if not p.is_absolute():
                p = d / p
        elif name:
            if "/" in name or "\\" in name or name == "..":
                raise BadInput(f"bad recording name {name!r}")
            p = d if name == "." else d / name
        else:
            raise BadInput('give "name" (a recording in the folder) or "path"')
        # only recordings in the recordings folder: a path must not reach any other folder
        if not p.resolve().is_relative_to(d.resolve()):
            raise Forbidden(f"{path or name}: not in the recordings folder {d}; copy the "
                            "recording there")
        if not p.is_dir():
            raise NotFound(f"no recording folder {p}")
        if not (p / "manifest.json").is_file():
            raise BadInput(f"{p} has no manifest.json: not a mission recording")
        return p

    def load(self, name: str | None = None, path: str | None = None) -> dict:
        p = self._resolve(name, path)
        try:
            manifest, ticks = load_recording(p)
        except (ValueError, KeyError, OSError) as e:
            raise BadInput(f"bad recording {p}: {one_line(e, 300)}") from None
        pb = Playback(p, manifest, ticks, self.clock)
        with self._setup:
            scene = self.scene
            if scene is not None and scene.server is not None:
                try:
                    scene.load(manifest)
                except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
                    # the playing recording stays loaded: a bad one never replaces it
                    raise BadInput(f"bad recording {p}: manifest.json: {one_line(e, 200)}") from None
            with self._lock:
                self.pb = pb
        self._ensure_thread()
        self._wake.set()
        return self.state()

    def _need(self) -> Playback:
        pb = self.pb
        if pb is None:
            raise Conflict("no recording loaded")
        return pb

    # --------------------------------------------------------------- controls
    def play(self) -> dict:
        self._need().play()
        self._wake.set()
        return self.state()

    def pause(self) -> dict:
        self._need().pause()
        self._wake.set()
        return self.state()

    def seek(self, t: float) -> dict:
        pb = self._need()
        if not math.isfinite(t):
            raise BadInput("t must be a number of seconds")
        pb.seek(t)
        self._wake.set()
        return self.state()

    def set_speed(self, x: float) -> dict:
        if not (math.isfinite(x) and 0.05 <= x <= 64):
            raise BadInput("speed must be between 0.05 and 64")
        self._need().set_speed(x)
        return self.state()

    def state(self) -> dict:
        with self._lock:
            pb, scene = self.pb, self.scene
        if pb is None:
            return {"loaded": False}
        t, playing, speed = pb.now()
        i = pb.index(t)
        tk = pb.ticks[i]
        ev = pb.events_so_far(i=i)
        return {
            "loaded": True, "name": pb.path.name, "path": str(pb.path),
            "scenario": pb.manifest.get("scenario"), "outcome": pb.manifest.get("outcome"),
            "t": round(t, 3), "duration": pb.duration, "playing": playing,
            "speed": speed, "state": tk["state"], "tick_t": tk["t"],
            "drone": tk["drone"], "setpoint": tk.get("setpoint"),
            "holding": tk.get("holding"), "picker": tk.get("picker"),
            "events": len(ev),
            "last_events": [{"t": e.get("t"), "kind": e.get("kind"), "text": _describe(e)}
                            for e in ev[-8:]],
            "placed": pb.placed(i), "bricks_total": _count(pb.manifest.get("bricks")),
            "scene_updates": scene.updates if scene is not None else 0,
            "note": pb.note,
        }

    # --------------------------------------------------------------- scene + thread
    def start_scene(self) -> ReplayScene | None:
        if self.scene is None:
            with self._setup:
                if self.scene is None:
                    scene = ReplayScene()
                    try:
                        scene.start()
                    except Exception:  # noqa: BLE001 - the panel works without the 3D view
                        return None
                    pb = self.pb
                    if pb is not None:
                        try:
                            scene.load(pb.manifest)
                        except (ValueError, KeyError, TypeError, IndexError, AttributeError):
                            log.debug("replay scene load failed", exc_info=True)
                    # given to the playback only once drawn: a draw before would be lost
                    with self._lock:
                        self.scene = scene
        self._ensure_thread()
        self._wake.set()
        return self.scene

    def _ensure_thread(self) -> None:
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._stop.clear()
                self._thread = threading.Thread(target=self._run, daemon=True,
                                                name="replay-playback")
                self._thread.start()

    def _run(self) -> None:
        """Draw the latest instant, again whenever it changes; the frames a slow draw spans
        are dropped (the time never waits for a draw: :class:`Playback`)."""
        shown: tuple | None = None
        while not self._stop.is_set():
            self._wake.clear()
            with self._lock:
                pb, scene = self.pb, self.scene
            playing = False
            if pb is not None and scene is not None:
                t, playing, _ = pb.now()
                i = pb.index(t)
                # the scene, recording and tick drawn: a new scene or recording is drawn anew
                key = (scene, pb, i)
                if key != shown:
                    try:
                        scene.show(pb.ticks[i], set(pb.placed(i)))
                        shown = key
                    except Exception:
                        log.debug("replay scene update failed", exc_info=True)
            self._wake.wait(self.period if playing else 0.5)

    def close(self) -> None:
        """Stop the playback and wait for its thread to end (a draw in progress finishes),
        then stop the scene: no thread of the replay's is left running as the interpreter
        exits. The bound only turns a hang into a message."""
        self._stop.set()
        self._wake.set()
        join_thread(self._thread, "playing a recording back")
        if self.scene is not None:
            self.scene.stop()
            self.scene = None
