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


def stop_waits_for_the_held_draw(scene: ViserScene, held: HeldDraw,
                                 first_draw: Callable[[], None]) -> None:
    """Stop ``scene`` from another thread while ``held`` blocks its draw: stop must not
    return before the draw is released, and the drawing thread must have ended when it does."""
    drawer_alive_after_stop: list[bool] = []

    def stop() -> None:
        scene.stop()
        drawer_alive_after_stop.append(held.drawers[0].is_alive())

    stopper = threading.Thread(target=stop, daemon=True, name="stopper")
    try:
        first_draw()
        assert held.drawing.wait(HANG), "the scene never drew"
        stopper.start()
        # the draw stays blocked a while after stop began (longer than a stop that gives up
        # after a few seconds waits), then returns
        stopper.join(HOLD)
        assert stopper.is_alive(), "stop returned while the draw was still blocked"
        held.release.set()
        stopper.join(HANG)
        assert not stopper.is_alive(), "stop never returned"
        assert drawer_alive_after_stop == [False], "stop returned before the draw ended"
        assert scene.server is None
    finally:
        held.release.set()
        if not stopper.is_alive():
            scene.stop()


def test_the_live_scene_stop_waits_for_the_draw_in_progress():
    scene = LiveScene().start()
    held = HeldDraw()
    scene._apply = held  # type: ignore[method-assign]
    stop_waits_for_the_held_draw(scene, held, lambda: scene.update(object()))


def test_the_fleet_scene_stop_waits_for_the_draw_in_progress():
    scene = FleetScene(Fleet(), max_hz=20.0).start()
    held = HeldDraw()
    scene.update = held  # type: ignore[method-assign]
    stop_waits_for_the_held_draw(scene, held, lambda: None)
