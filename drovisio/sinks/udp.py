"""``udp://HOST:PORT``: one JSON datagram per processed frame (fire and forget)."""

from __future__ import annotations

import json
import socket

from drovisio.sinks.base import Delivery, SinkError, host_port

__all__ = ["MAX_DATAGRAM", "UdpSink"]

MAX_DATAGRAM = 65000


class UdpSink:
    def __init__(self, host: str, port: int, with_covariance: bool = True):
        self.name = f"udp://{host}:{port}"
        self.addr = (host, int(port))
        self.with_covariance = with_covariance
        try:
            info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        except (socket.gaierror, UnicodeError) as e:
            raise SinkError(f"unknown host {host!r} ({e}); check the address") from e
        self.sock = socket.socket(info[0], socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.dest = info[4]
        self.delivery = Delivery()

    @classmethod
    def from_url(cls, url: str) -> UdpSink:
        return cls(*host_port(url, "udp://127.0.0.1:9870"))

    def send(self, output) -> None:
        data = json.dumps(output.to_json(self.with_covariance), separators=(",", ":")).encode()
        if len(data) > MAX_DATAGRAM:  # too many bricks for one datagram: drop the extras
            js = output.to_json(False)
            while len(data) > MAX_DATAGRAM and js["bricks"]:
                js["bricks"].pop()
                js["truncated"] = True
                data = json.dumps(js, separators=(",", ":")).encode()
        try:
            self.sock.sendto(data, self.dest)
        except OSError as e:  # no listener (ICMP refused), network down: count, go on
            self.delivery.failed(str(e))
            return
        self.delivery.delivered()

    def close(self) -> None:
        self.sock.close()

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status()}
