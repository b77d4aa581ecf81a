"""``ws://HOST:PORT``: a WebSocket server pushing each frame's JSON object to every client.

For other programs on the drone or the ground (a mission script, a logger). Each client gets
the newest objects; one that reads too slowly loses the oldest ones (at most ``queue``
objects wait per client), never slowing the pipeline. A client may send
``{"set_target": "LAYOUT:INSTANCE" | "nearest" | ...}`` to change the target at run time;
the server answers ``{"target": {...}}`` (or ``{"error": "..."}``).

Web pages are refused: a browser always sends ``Origin`` with a WebSocket, and any page the
laptop or the drone's tablet has open could otherwise change the flight controller's target
(a WebSocket is not bound by the same-origin policy). Programs send no ``Origin`` and are
accepted. Bind it to 127.0.0.1 (the default in examples) unless the network is trusted: it has
no token (the web tool, ``drovisio serve``, is the way to watch and steer from a browser).
"""

from __future__ import annotations

import asyncio
import json
import threading
from typing import Any

from drovisio._threads import join_thread
from drovisio.sinks.base import SinkError, host_port
from drovisio.sinks.target import TargetSelector

__all__ = ["WebSocketSink"]


class WebSocketSink:
    def __init__(self, host: str = "127.0.0.1", port: int = 8765,
                 target: TargetSelector | None = None, queue: int = 4):
        self.host = host
        self.target = target
        self.queue = queue
        self.sent = 0
        self.dropped = 0
        self._clients: dict[object, asyncio.Queue] = {}
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._server: Any = None
        self.port = port
        self._thread = threading.Thread(target=self._run, daemon=True, name="ws-sink")
        self._thread.start()
        self._ready.wait(10)
        if self._error is not None:
            raise SinkError(f"cannot listen on {host}:{port} ({self._error}); give an "
                            "address of this machine and a port no other program uses")
        self.name = f"ws://{host}:{self.port}"

    @classmethod
    def from_url(cls, url: str, target: TargetSelector | None = None) -> WebSocketSink:
        return cls(*host_port(url, "ws://127.0.0.1:8765", port_zero=True), target=target)

    # ------------------------------------------------------------------ server thread
    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._start())
        except BaseException as e:  # noqa: BLE001
            self._error = e
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()

    async def _start(self) -> None:
        from websockets.asyncio.server import serve

        # origins=[None]: only clients without an Origin header (programs, not web pages)
        self._server = await serve(self._handler, self.host, self.port, origins=[None])
        self.port = self._server.sockets[0].getsockname()[1]

    async def _handler(self, ws) -> None:
        q: asyncio.Queue = asyncio.Queue(maxsize=self.queue)
        self._clients[ws] = q

        async def pump() -> None:
            while True:
                data = await q.get()
                await ws.send(data)

        task = asyncio.ensure_future(pump())
        try:
            async for msg in ws:
                reply = self._control(msg)
                if reply is not None:
                    await ws.send(reply)
        except Exception:  # noqa: BLE001 - client went away
            pass
        finally:
            task.cancel()
            self._clients.pop(ws, None)

    def _control(self, msg) -> str | None:
        try:
            data = json.loads(msg)
        except (TypeError, ValueError):
            return json.dumps({"error": "expected JSON"})
        if isinstance(data, dict) and "set_target" in data:
            if self.target is None:
                return json.dumps({"error": "no target selector"})
            try:
                spec = self.target.set(data["set_target"])
            except (ValueError, TypeError) as e:
                return json.dumps({"error": str(e)})
            return json.dumps({"target": spec.to_json()})
        return None

    def _broadcast(self, data: str) -> None:
        for q in list(self._clients.values()):
            if q.full():
                try:
                    q.get_nowait()
                    self.dropped += 1
                except asyncio.QueueEmpty:
                    pass
            q.put_nowait(data)

    # ------------------------------------------------------------------ sink API
    @property
    def clients(self) -> int:
        return len(self._clients)

    def send(self, output) -> None:
        if not self._clients:
            return
        data = json.dumps(output.to_json(), separators=(",", ":"))
        self._loop.call_soon_threadsafe(self._broadcast, data)
        self.sent += 1

    def close(self) -> None:
        async def _close() -> None:
            if self._server is not None:
                self._server.close()
                await self._server.wait_closed()

        if self._loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(_close(), self._loop)
            try:
                fut.result(3)   # a client that never answers the close is not waited for
            except Exception:  # noqa: BLE001
                pass
        if self._thread.is_alive():   # also when the loop is only about to run
            self._loop.call_soon_threadsafe(self._loop.stop)
        join_thread(self._thread, f"serving {self.name}")

    def status(self) -> dict:
        return {"sink": self.name, "clients": self.clients, "sent": self.sent,
                "dropped": self.dropped}
