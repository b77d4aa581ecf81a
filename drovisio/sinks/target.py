"""Which brick is "the target" (the one the flight controller is sent), settable at run time.

Spec strings (``--target`` of ``drovisio run``, the live page, the WebSocket feed):

* ``nearest`` — the brick nearest to the drone (body origin; the camera without a mount);
* ``LAYOUT`` — the nearest brick of that layout;
* ``LAYOUT:INSTANCE`` — that brick (e.g. ``drick-aruco-pyramids:1``);
* ``track:N`` — the brick of track N (bricks without ids, e.g. dots; tracks count from 1);
* ``none`` — no target (nothing is sent to the flight controller).

A selector given the layouts in use refuses a spec no brick of them can meet (an unknown
layout, an instance number beyond the layout's ``instances``, an instance of a layout without
ids), whoever sets it: ``--target``, the live page, the WebSocket feed.

The choice follows a track: once a brick is the target it stays the target while its track
lives (measured, or held over for a missed frame), unless another brick of the spec is
clearly nearer (``switch_ratio``). What a flight controller is sent is another matter: only a
target measured in the frame (:mod:`drovisio.sinks.mavlink`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drovisio.bounds import parse_whole
from drovisio.errors import one_line

if TYPE_CHECKING:
    from drovisio.layout import MarkerLayout

__all__ = ["TargetSelector", "TargetSpec", "check_target", "parse_target"]


@dataclass(frozen=True)
class TargetSpec:
    mode: str  # "nearest" | "layout" | "brick" | "track" | "none"
    layout: str | None = None
    instance: int | None = None
    track: int | None = None

    def __str__(self) -> str:
        if self.mode == "brick":
            return f"{self.layout}:{self.instance}"
        if self.mode == "layout":
            return str(self.layout)
        if self.mode == "track":
            return f"track:{self.track}"
        return self.mode

    def to_json(self) -> dict:
        return {"mode": self.mode, "layout": self.layout, "instance": self.instance,
                "track": self.track, "spec": str(self)}


def parse_target(spec: str | dict | TargetSpec | None) -> TargetSpec:
    """A :class:`TargetSpec` from a string (see the module doc) or a dict
    ``{"mode": ..., "layout": ..., "instance": ..., "track": ...}``.

    Raises:
        ValueError: an unknown mode, or one without the fields it needs.
    """
    if spec is None:
        return TargetSpec("nearest")
    if isinstance(spec, TargetSpec):
        return spec
    if isinstance(spec, dict):
        return _target_from_dict(spec)
    return _target_from_string(str(spec).strip())


def _target_from_dict(spec: dict) -> TargetSpec:
    if "spec" in spec and isinstance(spec["spec"], str):
        return parse_target(spec["spec"])
    mode = spec.get("mode")
    layout, inst, track = spec.get("layout"), spec.get("instance"), spec.get("track")
    if mode is None:
        mode = ("track" if track is not None else "brick" if inst is not None
                else "layout" if layout else "nearest")
    if mode not in ("nearest", "layout", "brick", "track", "none"):
        raise ValueError(f"unknown target mode {mode!r}")
    if mode in ("layout", "brick") and not layout:
        raise ValueError("a target by layout needs 'layout'")
    if mode == "brick" and inst is None:
        raise ValueError("a target brick needs 'instance'")
    if mode == "track" and track is None:
        raise ValueError("a target track needs 'track'")
    return TargetSpec(mode, layout, None if inst is None else _instance(inst),
                      None if track is None else _track(track))


def _instance(value: object) -> int:
    try:
        return parse_whole(value, 0)
    except ValueError as e:
        raise ValueError(f"instance (LAYOUT:INSTANCE): {e}") from None


def _track(value: object) -> int:
    try:
        return parse_whole(value, 1)
    except ValueError as e:
        raise ValueError(f"track number: {e}") from None


def _target_from_string(s: str) -> TargetSpec:
    if s in ("", "nearest"):
        return TargetSpec("nearest")
    if s in ("none", "off"):
        return TargetSpec("none")
    if s.startswith("track:"):
        return TargetSpec("track", track=_track(s[6:]))
    if ":" in s:
        layout, _, inst = s.rpartition(":")
        return TargetSpec("brick", layout, _instance(inst))
    return TargetSpec("layout", s)


def check_target(spec: TargetSpec, layouts: Sequence[MarkerLayout]) -> TargetSpec:
    """``spec`` if a brick of ``layouts`` (the layouts in use) can meet it.

    Raises:
        ValueError: the layout is not in use, or it cannot have that instance.
    """
    if spec.mode not in ("layout", "brick"):
        return spec
    layout = next((lay for lay in layouts if lay.name == spec.layout), None)
    if layout is None:
        names = ", ".join(lay.name for lay in layouts) or "none"
        raise ValueError(f"no layout named {one_line(repr(spec.layout), 80)} is in use "
                         f"(in use: {one_line(names, 200)})")
    if spec.mode == "brick":
        if layout.instances is None:
            raise ValueError(f"the bricks of {layout.name} have no ids, so no instance "
                             f"number; give {layout.name} or track:N")
        if spec.instance is None or spec.instance >= layout.instances:
            raise ValueError(f"{layout.name} has instances 0 to {layout.instances - 1}; "
                             f"{spec.instance} is not one of them")
    return spec


class TargetSelector:
    """Chooses the target among a frame's tracked bricks; :meth:`set` may be called from any
    thread while the pipeline runs.

    Args:
        spec: The target spec (module doc).
        switch_ratio: With ``nearest`` or ``LAYOUT``, another brick takes over from the current
            target's track only when it is nearer by this factor (no flicker between two bricks
            at about the same distance).
        layouts: The layouts in use: every spec set is checked against them
            (:func:`check_target`); None: not checked.

    Raises:
        ValueError: a spec that cannot be parsed or met (here and in :meth:`set`).
    """

    def __init__(self, spec: str | dict | TargetSpec | None = "nearest",
                 switch_ratio: float = 0.8,
                 layouts: Sequence[MarkerLayout] | None = None):
        self._lock = threading.Lock()
        self.layouts = None if layouts is None else list(layouts)
        self._spec = self._checked(spec)
        self.switch_ratio = switch_ratio
        self._track: int | None = None

    def _checked(self, spec: str | dict | TargetSpec | None) -> TargetSpec:
        new = parse_target(spec)
        return new if self.layouts is None else check_target(new, self.layouts)

    @property
    def spec(self) -> TargetSpec:
        return self._spec

    def set(self, spec: str | dict | TargetSpec | None) -> TargetSpec:
        new = self._checked(spec)
        with self._lock:
            self._spec = new
            self._track = None
        return new

    def choose(self, bricks: Sequence):
        s = self._spec
        if s.mode == "none" or not bricks:
            return None
        if s.mode == "brick":
            c = [b for b in bricks if b.layout == s.layout and b.instance == s.instance]
        elif s.mode == "layout":
            c = [b for b in bricks if b.layout == s.layout]
        elif s.mode == "track":
            c = [b for b in bricks if b.track == s.track]
        else:
            c = list(bricks)
        if not c:
            return None
        nearest = min(c, key=lambda b: b.distance)
        current = next((b for b in c if b.track == self._track), None)
        if current is not None and nearest.distance >= self.switch_ratio * current.distance:
            return current
        self._track = nearest.track
        return nearest
