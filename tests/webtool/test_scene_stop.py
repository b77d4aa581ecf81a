"""Stopping a 3D scene (the app's shutdown, a live view closed) waits for its drawing thread:
a draw in progress runs numpy and the viewer's encoding, and a thread left running while the
interpreter exits can abort the process ("terminate called without an active exception").

Each scene runs its real viser server and drawing thread; one draw is held on an Event while
another thread stops the scene. Each wait is a bound that turns a hang into a failure, not a
timing."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from drovisio.station import Fleet
from webtool.fleet.scene import FleetScene
from webtool.live.scene import LiveScene
from webtool.viewer.scene import ViserScene

HANG = 60.0   # seconds: a bound for failures only
HOLD = 5.0    # seconds a draw stays blocked under stop (a stop that waits passes with any)


class HeldDraw:
    """A draw that tells the test it began, then waits until the test lets it finish."""

    def __init__(self) -> None:
        self.drawers: list[threading.Thread] = []
        self.drawing = threading.Event()
        self.release = threading.Event()

    def __call__(self, *args: Any) -> None:
        self.drawers.append(threading.current_thread())
        self.drawing.set()
        if not self.release.wait(HANG):
            raise TimeoutError("the test never released the draw")


def test_the_live_scene_stop_waits_for_the_draw_in_progress(stop_waits_for_held_work):
    scene = LiveScene().start()
    held = HeldDraw()
    scene._apply = held  # type: ignore[method-assign]
    _stop_waits(scene, held, lambda: scene.update(object()), stop_waits_for_held_work)


def test_the_fleet_scene_stop_waits_for_the_draw_in_progress(stop_waits_for_held_work):
    scene = FleetScene(Fleet(), max_hz=20.0).start()
    held = HeldDraw()
    scene.update = held  # type: ignore[method-assign]
    _stop_waits(scene, held, lambda: None, stop_waits_for_held_work)


def _stop_waits(scene: ViserScene, held: HeldDraw, first_draw: Callable[[], None],
                check: Callable[..., None]) -> None:
    """Stop ``scene`` from another thread while ``held`` blocks its draw: stop waits for the
    draw (``check``: the ``stop_waits_for_held_work`` fixture), and the server is gone."""
    try:
        first_draw()
        assert held.drawing.wait(HANG), "the scene never drew"
        check(scene.stop, lambda: held.drawers[0], held.release, "stop", hold=HOLD, hang=HANG)
        assert scene.server is None
    finally:
        held.release.set()
        scene.stop()
