"""The ground station's side of Zenoh: every drone's outputs and presence into a :class:`Fleet`.

Drones publish with ``drovisio run --sink zenoh:connect=tcp/STATION:7447 --drone-id ID``
(:mod:`drovisio.sinks.zenoh`): their ``output`` topic (the frame's JSON output as a
``std_msgs/String``) under rmw_zenoh's key ``<domain>/drovisio/<ID>/output/<type>/<hash>``,
their camera image at a low rate under ``.../camera/image_raw/compressed/...``, and a
liveliness token ``drovisio_lv/<domain>/<ID>`` that Zenoh withdraws the moment the drone's
session ends (a crash or ``kill -9`` closes its TCP link), so a lost drone is seen at once,
and at the latest after :data:`drovisio.station.fleet.LOST_AFTER_S` without frames.

Everything received is hostile until read: payloads over :data:`MAX_PAYLOAD` bytes, outputs
that are not a JSON object, and keys that name no drone are dropped and counted.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import Any

import zenoh

from drovisio.ros.msgdefs import decoder
from drovisio.station.fleet import Fleet

__all__ = ["LIVELINESS_PREFIX", "MAX_PAYLOAD", "StationLink", "liveliness_key"]

log = logging.getLogger("drovisio.station")

LIVELINESS_PREFIX = "drovisio_lv"
MAX_PAYLOAD = 4 * 1024 * 1024
"""Largest message read (bytes): a frame's output is a few kB, an image a few hundred."""


def liveliness_key(domain: int, drone_id: str | None) -> str:
    """The key of a drone's liveliness token (``_`` for a drone without an id)."""
    return f"{LIVELINESS_PREFIX}/{int(domain)}/{drone_id or '_'}"


def _drone_and_topic(key: str) -> tuple[str, str] | None:
    """(drone id, topic) of an rmw_zenoh key ``<domain>/drovisio/[<id>/]<topic...>/<type>/
    <hash>``; None when it is not one of a drone's topics."""
    chunks = key.split("/")
    if len(chunks) < 5 or chunks[1] != "drovisio":
        return None
    rest = chunks[2:-2]
    if rest and rest[0] in ("output", "camera", "bricks", "target", "info"):
        return "_", "/".join(rest)
    if len(rest) < 2:
        return None
    return rest[0], "/".join(rest[1:])


class StationLink:
    """A Zenoh session that listens for drones and feeds a :class:`Fleet`.

    Args:
        fleet: Where what arrives goes.
        listen: Endpoints to listen on (drones connect here), e.g. ``["tcp/0.0.0.0:7447"]``.
        connect: Endpoints to connect to (a router, or drones that listen).
        domain: The ROS domain id (the first chunk of every key).
    """

    def __init__(self, fleet: Fleet, listen: list[str] | None = None,
                 connect: list[str] | None = None, domain: int = 0):
        self.fleet = fleet
        self.domain = int(domain)
        self.dropped = 0
        self._lock = threading.Lock()
        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps("peer"))
        cfg.insert_json5("listen/endpoints", json.dumps(list(listen or [])))
        cfg.insert_json5("connect/endpoints", json.dumps(list(connect or [])))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/exit_on_failure", "false")
        cfg.insert_json5("connect/timeout_ms", "-1" if connect else "0")
        self._session = zenoh.open(cfg)
        self._decode_string = decoder("std_msgs/String")
        self._decode_image = decoder("sensor_msgs/CompressedImage")
        self._subs = [
            self._session.declare_subscriber(f"{self.domain}/drovisio/**", self._on_sample),
            self._session.liveliness().declare_subscriber(
                f"{LIVELINESS_PREFIX}/{self.domain}/*", self._on_presence, history=True),
        ]

    def _drop(self, why: str) -> None:
        with self._lock:
            self.dropped += 1
        log.debug("station: dropped a message: %s", why)

    def _on_sample(self, sample: Any) -> None:
        t_recv, mono = time.time(), time.monotonic()
        try:
            key = str(sample.key_expr)
            where = _drone_and_topic(key)
            if where is None:
                return
            drone, topic = where
            payload = sample.payload.to_bytes()
            if len(payload) > MAX_PAYLOAD:
                self._drop(f"{key}: {len(payload)} bytes")
                return
            if topic == "output":
                output = json.loads(self._decode_string(payload).data)
                if not isinstance(output, dict):
                    self._drop(f"{key}: not a JSON object")
                    return
                self.fleet.frame(drone, output, t_recv, mono)
            elif topic == "info":
                info = json.loads(self._decode_string(payload).data)
                web = info.get("web") if isinstance(info, dict) else None
                if isinstance(web, str) and web.startswith(("http://", "https://")) \
                        and len(web) <= 200:
                    self.fleet.describe(drone, {"web": web})
            elif topic == "camera/image_raw/compressed":
                msg = self._decode_image(payload)
                t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                self.fleet.image(drone, bytes(msg.data), t)
        except Exception as e:  # noqa: BLE001 - a bad message from the network is dropped
            self._drop(f"{type(e).__name__}: {e}")

    def _on_presence(self, sample: Any) -> None:
        drone = str(sample.key_expr).rsplit("/", 1)[-1]
        self.fleet.presence(drone, sample.kind == zenoh.SampleKind.PUT)

    def close(self) -> None:
        """Undeclare everything and close the session."""
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self._subs = []
        try:
            self._session.close()
        except Exception:  # noqa: BLE001
            pass
