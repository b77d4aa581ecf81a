"""Where the poses go: JSON Lines, UDP datagrams, MAVLink LANDING_TARGET, a WebSocket feed.

Every sink has ``send(output)`` (called by the pipeline once per processed frame, with a
:class:`drovisio.pipeline.FrameOutput`; it must return quickly and never raise for a network
or disk problem — it counts and reports it instead, through
:class:`drovisio.sinks.base.Delivery`: only what its link or file took is ``sent``),
``close()`` and ``status() -> dict``.

SINK strings (``--sink`` of ``drovisio run``, :func:`open_sink`):

* ``jsonl:-`` (stdout), ``jsonl:PATH`` — one JSON object per frame;
* ``udp://HOST:PORT`` — the same object as one UDP datagram per frame;
* ``mavlink:CONNECTION`` — ``LANDING_TARGET`` to a flight controller through pymavlink
  (``mavlink:udpout:127.0.0.1:14550``, ``mavlink:/dev/ttyAMA0,921600``), only for frames
  that measured the target;
* ``ws://HOST:PORT`` — a WebSocket server that pushes the objects to every connected client
  (and takes ``{"set_target": "..."}`` messages);
* ``zenoh:connect=tcp/HOST:PORT`` — the ROS 2 messages over Zenoh, keyed as rmw_zenoh keys
  them (:mod:`drovisio.sinks.zenoh`).
"""

from __future__ import annotations

from drovisio.sinks.base import Sink, SinkError
from drovisio.sinks.jsonl import JsonlSink
from drovisio.sinks.mavlink import MavlinkSink
from drovisio.sinks.target import TargetSelector, TargetSpec, parse_target
from drovisio.sinks.udp import UdpSink
from drovisio.sinks.websocket import WebSocketSink

__all__ = ["SINK_FORMS", "Sink", "SinkError", "TargetSelector", "TargetSpec", "open_sink",
           "parse_target"]


SINK_FORMS = ("jsonl:-, jsonl:PATH, udp://HOST:PORT, mavlink:CONNECTION, ws://HOST:PORT or "
              "zenoh:connect=tcp/HOST:PORT")
"""The SINK strings, for the line that refuses one."""


def open_sink(spec: str, *, target: TargetSelector | None = None, autopilot: str = "ardupilot",
              mount=None, layouts=None, send_held: bool = False, camera=None,
              drone_id: str | None = None) -> Sink:
    """Open the sink of a SINK string (see the module doc).

    Raises:
        SinkError: the sink cannot be opened, in the one line every sink's refusal takes:
            ``--sink SPEC: why; what to do``, the spec said once, here.
    """
    try:
        return _open(spec.strip(), target=target, autopilot=autopilot, mount=mount,
                     layouts=layouts, send_held=send_held, camera=camera, drone_id=drone_id)
    except SinkError as e:
        raise SinkError(e.why, spec=spec) from None
    except (OSError, ValueError) as e:  # a library's refusal (a port out of range, no socket)
        why = (e.strerror or str(e)) if isinstance(e, OSError) else str(e)
        raise SinkError(f"{why}; write the sink as one of {SINK_FORMS}", spec=spec) from None


def _open(s: str, *, target: TargetSelector | None, autopilot: str, mount, layouts,
          send_held: bool, camera, drone_id: str | None) -> Sink:
    if s.startswith("zenoh:"):
        # deferred: the ROS messages load OpenCV, which a process without this sink never needs
        from drovisio.ros.messages import RosMessages, namespace_for
        from drovisio.sinks.zenoh import ZenohSink

        ns, prefix = namespace_for(drone_id)
        return ZenohSink(s, RosMessages(camera, mount, layouts or (), namespace=ns,
                                        frame_prefix=prefix))
    if s.startswith("jsonl:"):
        return JsonlSink(s[len("jsonl:"):])
    if s.startswith("udp://"):
        return UdpSink.from_url(s)
    if s.startswith("mavlink:"):
        return MavlinkSink(s[len("mavlink:"):], autopilot=autopilot, target=target,
                           mount=mount, layouts=layouts, send_held=send_held)
    if s.startswith("ws://"):
        return WebSocketSink.from_url(s, target=target)
    raise SinkError(f"unknown sink: use {SINK_FORMS}")
