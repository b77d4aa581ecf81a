"""viser's browser client and its WebSocket, served through the web tool.

viser runs its own server on its own port; the 3D views of the live page and of the mission
replay are proxied through the FastAPI app instead of linked to that port, so that the app's
token access covers them and the viser servers can listen on 127.0.0.1 only.
"""

from __future__ import annotations

import asyncio
import gzip
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import Response
from starlette.requests import HTTPConnection
from websockets.asyncio.client import connect

from webtool.access import access_level, refuse_other_sites

__all__ = ["client_response", "proxy_socket", "viewer_router"]

_client_cache: dict[str, tuple[bytes, bytes]] = {}


def _viser_build() -> Path:
    import viser  # deferred: heavy, loaded when a 3D view is first asked for

    return Path(viser.__file__).resolve().parent / "client" / "build"


#: added to viser's page: its toasts (e.g. "software WebGL rendering") cover the embedded
#: scene and say nothing a site user can act on; on a phone its control panel is a bottom
#: sheet (scene tree, canvas and developer settings) that covers half the scene, and the
#: tool's pages carry every control they need (on wider screens it stays folded to a bar)
_CLIENT_STYLE = (b"<style>.mantine-Notifications-root{display:none!important}"
                 b'.mantine-Paper-root[style*="position: fixed"][style*="bottom: 0px"]'
                 b"{display:none!important}</style>")


def client_file(path: str) -> tuple[bytes, bytes] | None:
    """(raw, gzipped) of a file of viser's built client, cached."""
    if path in _client_cache:
        return _client_cache[path]
    root = _viser_build()
    parts = [p for p in path.split("/") if p and p != "."]
    if any(p == ".." for p in parts):
        return None
    f = root.joinpath(*parts) if parts else root / "index.html"
    if not f.is_file():
        return None
    raw = f.read_bytes()
    if f.suffix == ".html":
        raw = raw.replace(b"</head>", _CLIENT_STYLE + b"</head>", 1)
    _client_cache[path] = (raw, gzip.compress(raw, 6))
    return _client_cache[path]


TYPES = {".html": "text/html; charset=utf-8", ".js": "application/javascript",
          ".css": "text/css", ".png": "image/png", ".jpg": "image/jpeg", ".svg": "image/svg+xml",
          ".wasm": "application/wasm", ".json": "application/json"}



async def client_response(request: Request, path: str) -> Response:
    """A file of viser's built client (gzipped when the browser accepts it)."""
    got = await asyncio.to_thread(client_file, path)
    if got is None:
        raise HTTPException(404, "not found")
    raw, gz = got
    ctype = TYPES.get(Path(path or "index.html").suffix.lower(), "application/octet-stream")
    if "gzip" in request.headers.get("accept-encoding", ""):
        return Response(gz, media_type=ctype,
                        headers={"Content-Encoding": "gzip", "Vary": "Accept-Encoding"})
    return Response(raw, media_type=ctype)


async def proxy_socket(ws: WebSocket, port: int | None) -> None:
    """Relay a browser's WebSocket to the viser server on 127.0.0.1:``port``."""
    if port is None:
        await ws.close(code=1011)
        return
    protos = list(ws.scope.get("subprotocols") or [])
    try:
        # two messages queued at most: a browser that reads slowly stops this relay reading
        # from viser, whose own buffer then keeps only the newest state of each thing in
        # the scene (old frames dropped) instead of this relay buffering megabytes a client
        up = await connect(f"ws://127.0.0.1:{port}", subprotocols=protos or None,
                           max_size=None, compression=None, open_timeout=10, max_queue=2)
    except Exception:  # noqa: BLE001
        await ws.close(code=1011)
        return
    await ws.accept(subprotocol=up.subprotocol)

    async def downstream() -> None:
        async for m in up:
            if isinstance(m, bytes):
                await ws.send_bytes(m)
            else:
                await ws.send_text(m)

    async def upstream() -> None:
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return
            data = msg.get("bytes")
            await up.send(data if data is not None else msg.get("text") or "")

    tasks = [asyncio.create_task(downstream()), asyncio.create_task(upstream())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in tasks:
            t.cancel()
        try:
            await up.close()
            await ws.close()
        except (RuntimeError, WebSocketDisconnect, ConnectionError):
            pass


def viewer_router(prefix: str, tag: str,
                  start_scene: Callable[[HTTPConnection], Awaitable[Any]], *,
                  full_access_only: bool = False, start_for_client: bool = True) -> APIRouter:
    """``GET prefix/…`` (viser's client) and ``WebSocket prefix`` (relayed to the scene's
    port) of one area's 3D view; ``start_scene(conn)`` starts the scene (or gives None: the
    socket is closed).

    Args:
        prefix: Where the view is served (``/live/3d``…).
        tag: The OpenAPI tag.
        start_scene: Starts the area's scene and gives it (its ``port``), or None.
        full_access_only: The socket is refused to view-only links (a 3D view that edits).
        start_for_client: Start the scene when the client's files are asked for (else only
            when the socket opens).
    """
    router = APIRouter(prefix=prefix, tags=[tag])

    @router.get("/{path:path}")
    async def viser_client(request: Request, path: str = "") -> Response:
        if start_for_client:
            refuse_other_sites(request)  # a GET that starts a viser server
            await start_scene(request)
        return await client_response(request, path)

    @router.websocket("")
    async def viser_socket(ws: WebSocket) -> None:
        if full_access_only and access_level(ws) != "full":
            await ws.close(code=1008)      # view-only links cannot edit
            return
        sc = await start_scene(ws)
        await proxy_socket(ws, sc.port if sc is not None else None)

    return router
