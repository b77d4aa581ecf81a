"""The replay's time is read off the clock while playing: a draw of the 3D view that blocks,
whatever holds it, holds back neither the time nor the state nor the controls, and once it
returns the latest instant is drawn, the frames between dropped. Closing the service waits
for a blocked draw to end (nothing of the replay's left running as the interpreter exits).

The clock is the test's own (no wall-clock timing); each wait is a bound that turns a hang
into a failure."""

from __future__ import annotations

import threading

import pytest

from drovisio.mission.record import load_recording, write_recording
from drovisio.mission.scenario import load_scenario, shipped_scenario
from drovisio.mission.sim import SimParams, simulate
from webtool.replay.service import Playback, ReplayService
from webtool.settings import Settings

HANG = 60.0   # seconds: a bound for failures only
HOLD = 5.0    # seconds a draw stays blocked under close (a close that waits passes with any)


class Clock:
    """A clock that moves only when the test moves it."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class BlockedScene:
    """A replay scene whose draws wait until the test lets them finish."""

    server = object()     # started

    def __init__(self) -> None:
        self.updates = 0
        self.shown: list[float] = []
        self.drawers: list[threading.Thread] = []
        self.drawing = threading.Event()
        self.release = threading.Event()
        self.drawn = threading.Condition()

    def load(self, manifest: dict) -> None:
        pass

    def show(self, tick: dict, placed: set[str]) -> None:
        self.shown.append(tick["t"])
        self.drawers.append(threading.current_thread())
        self.drawing.set()
        if not self.release.wait(HANG):
            raise TimeoutError("the test never released the draw")
        with self.drawn:
            self.updates += 1
            self.drawn.notify_all()

    def stop(self) -> None:
        self.release.set()


def _answer(fn, *args):
    """fn(*args) in a thread of its own: a call that waits on the blocked draw fails."""
    out: list = []

    def call() -> None:
        try:
            out.append(fn(*args))
        except Exception as e:  # noqa: BLE001 - raised again in the test's thread
            out.append(e)

    th = threading.Thread(target=call, daemon=True)
    th.start()
    th.join(HANG)
    assert out, f"{fn.__name__} waited on the blocked draw"
    if isinstance(out[0], Exception):
        raise out[0]
    return out[0]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("replays")
    scn = load_scenario(shipped_scenario()).subset(["b1"])
    write_recording(simulate(scn, params=SimParams(seed=2)), d / "one-brick", every=2)
    return d


def test_the_clock_runs_while_a_draw_is_blocked(recordings):
    clock = Clock()
    svc = ReplayService(Settings(replay_dir=recordings), clock=clock)
    scene = BlockedScene()
    svc.scene = scene  # type: ignore[assignment]
    try:
        st = svc.load("one-brick")
        assert scene.drawing.wait(HANG), "the playback never drew"   # ...and is stuck there
        t0 = st["t"]
        assert _answer(svc.set_speed, 4.0)["speed"] == 4.0
        assert _answer(svc.play)["playing"]
        clock.now += 2.5
        st = _answer(svc.state)
        assert st["t"] == t0 + 10.0 and st["playing"]
        ticks = load_recording(recordings / "one-brick")[1]
        tick = max((tk for tk in ticks if tk["t"] <= st["t"]), key=lambda tk: tk["t"])
        assert (st["tick_t"], st["state"], st["drone"]) == (tick["t"], tick["state"],
                                                            tick["drone"])
        # pausing, seeking and playing to the end answer too, and the end stops the clock
        assert _answer(svc.pause)["t"] == t0 + 10.0
        clock.now += 5.0
        assert _answer(svc.state)["t"] == t0 + 10.0
        assert _answer(svc.seek, 20.0)["t"] == 20.0
        _answer(svc.play)
        clock.now += 1e4
        st = _answer(svc.state)
        assert st["t"] == st["duration"] and not st["playing"] and st["state"] == "DONE"
        # the draw returns: the latest instant is drawn next, nothing in between
        scene.release.set()
        with scene.drawn:
            assert scene.drawn.wait_for(lambda: scene.updates >= 2, HANG)
        assert scene.shown == [ticks[0]["t"], ticks[-1]["t"]]
    finally:
        scene.release.set()
        svc.close()


def test_close_waits_for_the_blocked_draw_to_end(recordings, stop_waits_for_held_work):
    svc = ReplayService(Settings(replay_dir=recordings), clock=Clock())
    scene = BlockedScene()
    svc.scene = scene  # type: ignore[assignment]
    try:
        svc.load("one-brick")
        assert scene.drawing.wait(HANG), "the playback never drew"
        # the draw stays blocked a while after close began, then returns
        stop_waits_for_held_work(svc.close, lambda: scene.drawers[0], scene.release, "close",
                                 hold=HOLD, hang=HANG)
    finally:
        scene.release.set()


def test_the_time_is_read_off_the_clock(recordings):
    """t = t0 + speed × (clock − w0), set anew by play, pause, seek and speed."""
    clock = Clock()
    manifest, ticks = load_recording(recordings / "one-brick")
    pb = Playback(recordings / "one-brick", manifest, ticks, clock)
    t0 = pb.times[0]
    clock.now += 3.0
    assert pb.now() == (t0, False, 1.0)                # paused: the clock does not count
    pb.play()
    clock.now += 2.0
    assert pb.t == t0 + 2.0
    pb.set_speed(8.0)
    clock.now += 0.5
    assert pb.t == t0 + 6.0
    pb.seek(1.0)
    assert pb.t == 1.0
    clock.now += 0.25
    assert pb.now() == (3.0, True, 8.0)                # seeking while playing plays on
    pb.pause()
    clock.now += 10.0
    assert pb.now() == (3.0, False, 8.0)
    pb.play()
    clock.now += pb.duration
    assert pb.now() == (pb.duration, False, 8.0)       # the end stops the clock
    pb.play()
    assert pb.now() == (t0, True, 8.0)                 # ...and play starts again
