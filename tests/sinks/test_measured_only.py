"""The flight controller hears only what the camera saw: a LANDING_TARGET carries the target
measured in the frame it is stamped with, never a held-over (predicted) one — for ArduPilot
(BODY_FRD) and PX4 (LOCAL_NED) alike. Other sinks say which bricks are measured."""

from __future__ import annotations

import json
import math
import socket
import time

import numpy as np
import pytest

from drovisio.detect.result import BrickPose
from drovisio.mount import Mount
from drovisio.pipeline import Pipeline
from drovisio.sinks import open_sink
from drovisio.sinks.mavlink import mavutil2
from drovisio.sinks.target import TargetSelector
from drovisio.sources import EndOfStream, FrameSource, RawFrame

FPS = 30.0


class Scripted:
    """Frames 0..n-1 at 30 fps (media time): frame i shows the brick at ``script[i]`` (a
    distance in metres) or nothing (None)."""

    label = "scripted camera"
    finite = True
    lossless = False

    def __init__(self, script: list[float | None]):
        self.script = script
        self.i = 0

    def open(self) -> None:
        pass

    def read(self) -> RawFrame:
        if self.i >= len(self.script):
            raise EndOfStream()
        i = self.i
        self.i += 1
        img = np.full((48, 64, 3), i % 250, np.uint8)
        img[0, 0, 0] = i % 256            # the detector reads the frame number back
        img[0, 0, 1] = i // 256
        return RawFrame(img, i, media_time=i / FPS)

    def close(self) -> None:
        pass


class ScriptedDetector:
    """The brick of frame i at the scripted distance along the optical axis, slightly to the
    right (so that angle_x tells frames apart too)."""

    name = "scripted"

    def __init__(self, script, sway: bool = True):
        self.script = script
        self.sway = sway

    def detect(self, image, gravity=None):
        i = int(image[0, 0, 0]) + 256 * int(image[0, 0, 1])
        d = self.script[i]
        if d is None:
            return []
        return [BrickPose("drick-aruco-centre", 1, "aruco", np.array([math.pi, 0.0, 0.0]),
                          np.array([_x(i) if self.sway else 0.0, 0.0, d]), 0.2, markers=[21],
                          covariance=np.diag([1e-4] * 3 + [1e-6] * 3))]


def _x(i: int) -> float:
    return 0.02 * (i % 7)


class Listener:
    """A pymavlink endpoint standing in for the flight controller."""

    def __init__(self):
        mavutil = mavutil2()
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1,
                                               source_component=1)
        self.port = self.conn.port.getsockname()[1]

    def drain(self, n: int) -> list:
        """The ``n`` messages already sent, waited for (the bound only turns a lost message
        into a failure: a loaded machine delivers late, not never)."""
        out, deadline = [], time.monotonic() + 60
        while len(out) < n and time.monotonic() < deadline:
            m = self.conn.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.5)
            if m is not None:
                out.append(m)
        return out

    def close(self):
        self.conn.close()


def run(script, autopilot="ardupilot", send_held=False, extra_sinks=(), sway=False):
    """Run the pipeline over the script; (frame outputs, LANDING_TARGET messages, sinks)."""
    lst = Listener()
    target = TargetSelector("nearest")
    mount = Mount.from_angles(0.0)                        # looking straight down
    sinks = [open_sink(f"mavlink:udpout:127.0.0.1:{lst.port}", target=target,
                       autopilot=autopilot, mount=mount, send_held=send_held),
             *[open_sink(s, target=target) for s in extra_sinks]]
    p = Pipeline(FrameSource(Scripted(script), pace="max"), [ScriptedDetector(script, sway)],
                 sinks=sinks, mount=mount, target=target, max_age=0.5)
    outs = []
    p.add_listener(lambda f, o: o is not None and outs.append(o))
    try:
        p.run()
        msgs = lst.drain(sinks[0].delivery.sent)
    finally:
        p.close()
        lst.close()
    return outs, msgs, sinks


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_nothing_is_sent_after_the_brick_left_the_image(autopilot):
    script = [1.5] * 45 + [None] * 15          # seen for 45 frames, then an empty view
    outs, msgs, sinks = run(script, autopilot)
    last_measured = max(o.t for o in outs if any(b.measured for b in o.bricks))
    held = [o for o in outs if o.bricks and not any(b.measured for b in o.bricks)]
    assert held, "the tracker held the brick over some empty frames (the test needs them)"
    assert len(msgs) == 45
    assert max(m.time_usec for m in msgs) == int(round(last_measured * 1e6))
    assert sinks[0].status()["held_not_sent"] == len(held)


def test_every_message_is_the_frame_it_is_stamped_with():
    rng = np.random.default_rng(3)
    script = [None if rng.random() < 0.3 else float(rng.uniform(0.5, 2.0)) for _ in range(90)]
    outs, msgs, _ = run(script, sway=True)
    by_time = {int(round(o.t * 1e6)): o.frame for o in outs}
    measured = [o for o in outs if any(b.measured for b in o.bricks)]
    # a jump the tracker takes for an outlier is not "measured" (restarted on the next one)
    assert len(msgs) == len(measured) >= 0.5 * sum(d is not None for d in script)
    for m in msgs:
        frame = by_time[m.time_usec]
        d = script[frame]
        assert d is not None, f"message stamped with frame {frame}, which showed no brick"
        x = _x(frame)
        # camera looking down at the body origin: body distance = camera distance
        assert m.distance == pytest.approx(math.hypot(x, d), abs=1e-4)
        assert m.angle_x == pytest.approx(math.atan2(x, d), abs=1e-5)


def test_held_targets_are_sent_only_on_request_with_their_own_time():
    script = [1.2] * 20 + [None] * 6
    outs, msgs, _ = run(script, send_held=True)
    last_measured = max(o.t for o in outs if any(b.measured for b in o.bricks))
    after = [m for m in msgs[20:]]
    assert len(msgs) > 20 and after
    assert all(m.time_usec == int(round(last_measured * 1e6)) for m in after)


def test_udp_and_jsonl_say_which_bricks_are_measured(tmp_path):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    port = rx.getsockname()[1]
    script = [1.0] * 5 + [None] * 3
    run(script, extra_sinks=[f"udp://127.0.0.1:{port}", f"jsonl:{tmp_path / 'o.jsonl'}"])
    datagrams = []
    try:
        while True:
            datagrams.append(json.loads(rx.recv(65536)))
    except TimeoutError:
        pass
    finally:
        rx.close()
    lines = [json.loads(x) for x in (tmp_path / "o.jsonl").read_text().splitlines()]
    for stream in (datagrams, lines):
        bricks = [b for o in stream for b in o["bricks"]]
        assert {b["measured"] for b in bricks} == {True, False}
        assert all("age" in b for b in bricks)
        assert all(b["age"] > 0 for b in bricks if not b["measured"])
