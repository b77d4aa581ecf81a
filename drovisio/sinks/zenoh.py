"""``zenoh:...``: the run's ROS 2 messages over Zenoh, keyed as rmw_zenoh keys them.

A ROS 2 system running ``rmw_zenoh`` subscribes to these with plain ROS tools
(``ros2 topic echo /drovisio/drone1/target``). Each message of
:class:`drovisio.ros.messages.RosMessages` (the same CDR bytes an MCAP recording holds) is put
on the key expression rmw_zenoh's design document gives a topic::

    <domain id>/<fully qualified topic, without its leading />/<DDS type name>/<type hash>
    0/drovisio/drone1/bricks/vision_msgs::msg::dds_::Detection3DArray_/RIHS01_…

with rmw_zenoh's attachment (sequence number, source timestamp in ns, a 16-byte publisher
gid; zenoh-ext's serialization: two little-endian int64 and 16 bytes). Topics are under
``/drovisio/<drone id>`` (``--drone-id``; frame ids get ``<drone id>/`` in front), so that a
site's drones do not mix. ``/tf_static`` (the mount) is put again every second: this sink
keeps no publication cache for late joiners.

SINK string: ``zenoh:`` followed by ``&``-separated options: ``connect=ENDPOINT[,ENDPOINT]``
(e.g. ``tcp/192.168.1.10:7447``, a router or the ground station), ``listen=ENDPOINT``,
``mode=peer|client`` (default peer), ``domain=N`` (the ROS domain id, default 0),
``web=URL`` (this drone's web tool, linked from a station's Fleet page; sent once a second
on ``info``). Multicast
scouting is off (a site's Wi-Fi rarely carries it): give ``connect`` or ``listen``.

Never in the flight controller's way: :meth:`ZenohSink.send` only queues (a bounded queue;
the oldest frame is dropped when the link is slow, counted); a background thread opens the
session and publishes with congestion control *drop*. Zenoh reconnects a lost link by itself
(``connect/retry``), so a link that comes back carries the next frames without a restart.
A frame is counted as sent only when a peer or router is connected to take it: one that
waited for a session that did not open, or met nobody connected (Zenoh would drop it without
a word), is counted as lost (:class:`drovisio.sinks.base.Delivery`).

The session is closed by the thread that opened it, once it stops; a sink still open when
the interpreter exits is closed by an ``atexit`` hook first: Zenoh's runtime must not be
used while the process tears down (a session left to the interpreter's finalization, or one
closed from Zenoh's own exit handler, can abort the process). A close while the session is
still being opened (a router or station that does not answer) waits
:data:`OPENING_WAIT_S` at most, then says so in one warning naming the endpoints and goes
on: the process still ends.
"""

from __future__ import annotations

import atexit
import json
import math
import os
import queue
import struct
import threading
import time
import weakref
from typing import Any

from drovisio._threads import join_thread
from drovisio.ros.messages import TOPIC_TYPES, RosMessages
from drovisio.ros.msgdefs import encoder
from drovisio.ros.type_hash import dds_type_name, full_name, rihs01
from drovisio.sinks.base import Delivery, SinkError
from drovisio.zenoh_endpoint import ENDPOINT_HELP, endpoint_problem

__all__ = ["ZenohSink", "parse_spec", "topic_key"]

IMAGE_HZ = 1.0
"""Camera images a second sent for a station's thumbnail (the ROS image topic, small)."""
IMAGE_WIDTH = 320
"""Their width in pixels."""
OPENING_WAIT_S = 3.0
"""How long a close waits for a session still being opened: nothing cuts ``zenoh.open``
short (a client waits for its router for ever), so the close then goes on without it, said
in one warning naming the endpoints."""

_OPEN_SINKS: weakref.WeakSet[ZenohSink] = weakref.WeakSet()
"""Sinks not closed yet (closed at interpreter exit, see the module doc)."""


@atexit.register
def _close_open_sinks() -> None:
    for sink in list(_OPEN_SINKS):
        sink.close()


def topic_key(domain: int, topic: str, type_name: str) -> str:
    """rmw_zenoh's key expression of a topic."""
    return f"{int(domain)}/{topic.strip('/')}/{dds_type_name(type_name)}/{rihs01(type_name)}"


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment: sequence number, source timestamp (ns), 16-byte gid."""
    return struct.pack("<qq", int(seq), int(stamp_ns)) + bytes(gid[:16]).ljust(16, b"\0")


def parse_spec(spec: str) -> dict:
    """Options of a ``zenoh:...`` SINK string (module doc).

    Raises:
        SinkError: naming the option and what to write (the spec is said by
            :func:`drovisio.sinks.open_sink`).
    """
    body = spec[len("zenoh:"):] if spec.startswith("zenoh:") else spec
    opts: dict = {"connect": [], "listen": [], "mode": "peer", "domain": 0, "web": None}
    for part in filter(None, body.split("&")):
        key, eq, value = part.partition("=")
        if not eq or not value:
            raise SinkError(f"{part!r}: expected KEY=VALUE (connect=tcp/HOST:PORT, "
                            "listen=tcp/HOST:PORT, mode=peer|client, domain=N)")
        if key in ("connect", "listen"):
            for ep in value.split(","):
                problem = endpoint_problem(ep)
                if problem:
                    raise SinkError(f"{key}: {ep[:80]!r} {problem}: {ENDPOINT_HELP}")
                opts[key].append(ep)
        elif key == "mode":
            if value not in ("peer", "client"):
                raise SinkError(f"mode: {value!r}: use peer or client")
            opts["mode"] = value
        elif key == "web":
            if not value.startswith(("http://", "https://")) or len(value) > 200 \
                    or any(c in value for c in " \"'<>"):
                raise SinkError(f"web: {value!r}: give this drone's web tool address, "
                                "e.g. web=http://192.168.1.21:8080/")
            opts["web"] = value
        elif key == "domain":
            if not value.isdigit() or int(value) > 232:
                raise SinkError(f"domain: {value!r}: use a ROS domain id, 0–232")
            opts["domain"] = int(value)
        else:
            raise SinkError(f"unknown option {key!r}: use connect, listen, mode, "
                            "domain or web")
    if opts["mode"] == "client" and not opts["connect"]:
        raise SinkError("mode=client needs connect=tcp/HOST:PORT (a router)")
    if not opts["connect"] and not opts["listen"]:
        raise SinkError("give connect=tcp/HOST:PORT (the station or a router) or "
                        "listen=tcp/HOST:PORT")
    return opts


class ZenohSink:
    """Publishes each frame's ROS 2 messages over Zenoh (module doc).

    Args:
        spec: The SINK string.
        messages: The message builder (camera, mount, layouts; its namespace carries the
            drone id).
        queue_frames: Frames waiting at most (older ones are dropped when the link is slow):
            16, half a second at 30 fps, so that a busy machine's stall loses nothing.
    """

    def __init__(self, spec: str, messages: RosMessages, queue_frames: int = 16):
        self.opts = parse_spec(spec)
        self.name = spec
        self.messages = messages
        ns = messages.namespace.strip("/").split("/")
        self.drone_id: str | None = ns[1] if len(ns) > 1 else None
        self.domain = self.opts["domain"]
        self.delivery = Delivery()
        self.dropped = 0
        self._ends = ", ".join(self.opts["connect"] + self.opts["listen"])
        self._nobody = (f"{spec}: no Zenoh peer or router connected on {self._ends}; check "
                        "that the station (or router) runs and the network reaches it")
        self._seq: dict[str, int] = {}
        self._gid = os.urandom(16)
        self._keys: dict[tuple[str, str], str] = {}
        self._q: queue.Queue = queue.Queue(maxsize=queue_frames)
        self._session: Any = None
        self._session_lock = threading.Lock()
        self._session_closed = False
        self._stop = threading.Event()
        self._closed = False
        self._last_tf = 0.0
        self._token: Any = None
        self._image: tuple[float, Any] | None = None   # (capture time, BGR frame) to send
        self._last_image = -math.inf
        self._thread = threading.Thread(target=self._run, daemon=True, name="zenoh-sink")
        _OPEN_SINKS.add(self)
        self._thread.start()

    # ------------------------------------------------------------------ session
    def _config(self):
        import zenoh

        o = self.opts
        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps(o["mode"]))
        cfg.insert_json5("connect/endpoints", json.dumps(o["connect"]))
        cfg.insert_json5("listen/endpoints", json.dumps(o["listen"]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        # keep trying a station that is not there yet (the session opens in the sink's own
        # thread: waiting there holds nothing up) or went away (never give up)
        cfg.insert_json5("connect/timeout_ms", "-1" if o["connect"] else "0")
        cfg.insert_json5("connect/exit_on_failure", "false")
        cfg.insert_json5("connect/retry", json.dumps({"period_init_ms": 250,
                                                      "period_max_ms": 2000,
                                                      "period_increase_factor": 2}))
        return cfg

    def _run(self) -> None:
        import zenoh

        if self._stop.is_set():   # closed before it began: nothing to open
            return
        try:
            self._session = zenoh.open(self._config())
            # held while the session lives: a station sees this drone go the moment the
            # process ends, however it ends
            self._token = self._session.liveliness().declare_token(
                f"drovisio_lv/{self.domain}/{self.drone_id or '_'}")
        except Exception as e:  # noqa: BLE001 - said in the status, the pipeline goes on
            self.delivery.failed(f"{self.name}: cannot open a Zenoh session: {e}")
            return
        try:
            while not self._stop.is_set():
                try:
                    item = self._q.get(timeout=0.5)
                except queue.Empty:
                    continue
                if item is None:
                    break
                try:
                    self._publish(item)
                except Exception as e:  # noqa: BLE001
                    self.delivery.failed(str(e))
        finally:
            # also when close() gave up waiting while the session was still being opened
            self._close_session()

    def _close_session(self) -> None:
        """Close the session once (from its thread or from :meth:`close`)."""
        with self._session_lock:
            if self._session is None or self._session_closed:
                return
            self._session_closed = True
            session, token = self._session, self._token
        try:
            if token is not None:
                token.undeclare()
            session.close()
        except Exception:  # noqa: BLE001
            pass

    def _key(self, topic: str, type_name: str) -> str:
        k = self._keys.get((topic, type_name))
        if k is None:
            k = self._keys[(topic, type_name)] = topic_key(self.domain, topic, type_name)
        return k

    def _put(self, topic: str, type_name: str, msg: dict, t: float) -> None:
        import zenoh

        seq = self._seq.get(topic, 0) + 1
        self._seq[topic] = seq
        assert self._session is not None
        self._session.put(self._key(topic, full_name(type_name)), encoder(type_name)(msg),
                          congestion_control=zenoh.CongestionControl.DROP,
                          attachment=attachment(seq, int(t * 1e9), self._gid))

    def _publish(self, output) -> None:
        info = self._session.info
        if not info.peers_zid() and not info.routers_zid():   # Zenoh would drop it silently
            self.delivery.dropped(self._nobody)
            return
        now = time.monotonic()
        image, self._image = self._image, None
        if image is not None:
            self._put_image(*image)
        if now - self._last_tf >= 1.0:   # the mount and the camera, once a second
            m = self.messages
            for topic, type_name, msg in m.run_messages(output.t):
                self._put(topic, type_name, msg, output.t)
            if m.camera is not None:
                self._put(m.topic("camera/camera_info"), TOPIC_TYPES["camera/camera_info"],
                          m.camera_info(output.t), output.t)
            if self.opts["web"]:   # for a station's Fleet page: a link to this drone's tool
                self._put(m.topic("info"), "std_msgs/msg/String",
                          {"data": json.dumps({"web": self.opts["web"]})}, output.t)
            self._last_tf = now
        for topic, type_name, msg in self.messages.frame_messages(output, None):
            self._put(topic, type_name, msg, output.t)
        self.delivery.delivered()

    def _put_image(self, t: float, bgr: Any) -> None:
        import cv2

        h, w = bgr.shape[:2]
        scale = min(1.0, IMAGE_WIDTH / max(w, 1))
        small = cv2.resize(bgr, (max(1, round(w * scale)), max(1, round(h * scale))),
                           interpolation=cv2.INTER_AREA) if scale < 1 else bgr
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 70])
        if ok:
            m = self.messages
            self._put(m.topic("camera/image_raw/compressed"),
                      TOPIC_TYPES["camera/image_raw/compressed"],
                      m.compressed_image(buf.tobytes(), t, m.camera_frame), t)

    # ------------------------------------------------------------------ sink API
    def on_frame(self, frame, output) -> None:
        """A pipeline listener: keeps one camera image a second (small, JPEG) to send
        with the next frame's messages, for a station's thumbnail."""
        now = time.monotonic()
        if frame is None or output is None or getattr(frame, "image", None) is None \
                or now - self._last_image < 1.0 / IMAGE_HZ:
            return
        self._last_image = now
        self._image = (output.t, frame.image)

    def send(self, output) -> None:
        """Queue the frame (never waits: the oldest queued frame gives way: ``dropped`` on a
        slow link, ``lost`` while no session is open to take it)."""
        while True:
            try:
                self._q.put_nowait(output)
                return
            except queue.Full:
                try:
                    self._q.get_nowait()
                except queue.Empty:
                    continue
                if self._session is None:
                    self.delivery.dropped(self.delivery.last_error or self._nobody)
                else:
                    self.dropped += 1

    def close(self) -> None:
        if self._closed:          # a second close neither waits nor warns again
            return
        self._closed = True
        self._stop.set()
        try:
            self._q.put_nowait(None)
        except queue.Full:
            pass
        if self._session is None:
            # still opening: zenoh.open retries a missing station for ever and nothing can cut
            # it short, so only a short wait (the thread closes the session if it ever opens)
            join_thread(self._thread, f"opening a Zenoh session to {self._ends}, which did "
                        "not answer", limit=OPENING_WAIT_S)
        else:
            join_thread(self._thread, f"publishing to {self.name}")
        self._close_session()
        _OPEN_SINKS.discard(self)

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status(), "dropped": self.dropped,
                "state": "open" if self._session is not None else "connecting"}
