"""One base for the web tool's 3D views (viser servers): start, port, stop, and the guard
that only the tool's own proxy may talk to them.

viser runs its own HTTP/WebSocket server on its own port; the tool starts each on 127.0.0.1
and serves it to browsers through the app (``/live/3d``, ``/designer/3d``, ``/replay/3d``,
:mod:`webtool.viewer.proxy`), where the access middleware checks Host, Origin and token. The
port itself must not be a back door: any web page can open a WebSocket to 127.0.0.1 on any
port. So a viser server started here refuses every HTTP request or WebSocket that carries an
``Origin`` header — which every browser sends and the tool's proxy does not. viser has no
option for this; the guard wraps the ``process_request`` hook of the ``websockets`` server that
viser starts (checked by a test that opens the port the way a foreign page would).
"""

from __future__ import annotations

import http
import threading
import types
from typing import Any, Literal

__all__ = ["ViserScene", "refuses_browsers"]


def _guarded_serve(serve: Any) -> Any:
    def serve_without_browsers(*args: Any, **kwargs: Any) -> Any:
        inner = kwargs.get("process_request")

        def process_request(connection: Any, request: Any) -> Any:
            if request.headers.get("Origin") is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN,
                                          "open the 3D view through the Drovisio web tool\n")
            return inner(connection, request) if inner is not None else None

        kwargs["process_request"] = process_request
        return serve(*args, **kwargs)

    return serve_without_browsers


def _install_guard() -> None:
    """Give viser's infrastructure module a ``websockets`` whose ``serve`` refuses browsers
    (only that module sees it; everything else keeps the real one)."""
    # deferred: viser is heavy, loaded when the first 3D view starts
    import websockets
    import websockets.asyncio.server as ws_server
    from viser.infra import _infra

    if getattr(_infra, "_drovisio_guard", False):
        return
    server_ns = types.SimpleNamespace(**{k: getattr(ws_server, k) for k in dir(ws_server)
                                         if not k.startswith("__")})
    server_ns.serve = _guarded_serve(ws_server.serve)
    shim = types.SimpleNamespace(
        asyncio=types.SimpleNamespace(server=server_ns),
        datastructures=websockets.datastructures,
        exceptions=websockets.exceptions,
    )
    setattr(_infra, "websockets", shim)  # noqa: B010 - a module attribute replaced on purpose
    _infra._drovisio_guard = True  # type: ignore[attr-defined]


def refuses_browsers() -> bool:
    """True once the guard is in place (tests check the running servers themselves)."""
    from viser.infra import _infra  # deferred: heavy (see _install_guard)

    return bool(getattr(_infra, "_drovisio_guard", False))


class ViserScene:
    """A viser server on 127.0.0.1 (own port), started on first use, behind the guard.

    Subclasses draw in :meth:`setup` (called once the server runs, under the lock).

    Args:
        label: What the browser tab shows.
        up: The scene's up direction (``"+z"``, ``"-z"``…).
    """

    label = "Drovisio"
    up: Literal["+x", "+y", "+z", "-x", "-y", "-z"] = "+z"

    def __init__(self) -> None:
        self.server: Any = None
        self._lock = threading.RLock()

    @property
    def port(self) -> int | None:
        return None if self.server is None else int(self.server.get_port())

    def start(self) -> ViserScene:
        with self._lock:
            if self.server is None:
                import viser  # deferred: heavy, loaded when the first 3D view starts

                _install_guard()
                server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False,
                                           label=self.label)
                server.scene.set_up_direction(self.up)
                # the tool's pages carry the controls; viser's own panel (scene tree, canvas
                # and developer settings) starts folded to a thin bar so the scene has the room
                server.gui.configure_theme(control_width="small", show_logo=False,
                                           show_share_button=False, brand_color=(11, 79, 168))
                server.gui.main_panel.minimize()
                self.server = server
                self.setup()
        return self

    def setup(self) -> None:
        """Draw what does not change (subclasses)."""

    def stop(self) -> None:
        with self._lock:
            if self.server is not None:
                try:
                    self.server.stop()
                finally:
                    self.server = None

    def clients(self) -> int:
        return 0 if self.server is None else len(self.server.get_clients())
