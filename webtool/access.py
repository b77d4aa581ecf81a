"""Token access for a web tool that listens beyond this machine.

With ``token=None`` this middleware lets everything through (the default: bound to 127.0.0.1).
With a token, a request from a loopback client (127.0.0.0/8, ::1, "localhost") still passes;
any other client must present the token, in one of three ways:

* ``?token=...`` in the URL (what `drovisio serve` prints); a valid one also sets a cookie so that
  links and API calls from that page work without repeating it,
* the ``drovisio_token`` cookie,
* an ``Authorization: Bearer ...`` header (scripts).

Otherwise: 401 with a short explanation (JSON for /api/ and clients that ask for JSON, HTML
otherwise); a WebSocket is closed before it is accepted.

A second, **read-only viewer token** (``Settings.viewer_token``; presented the same three
ways) lets a person watch — every page, GET/HEAD request and WebSocket — but not change
anything: writes (POST, PUT, PATCH, DELETE) answer 403. Routes see the access level as
``request.state.drovisio_access`` (``"full"`` or ``"viewer"``; :func:`access_level`) and must
not accept changes over a WebSocket from a viewer. :func:`terminal_qr` and
:func:`access_lines` give what `drovisio serve` prints for phones (the links and QR codes).
"""

from __future__ import annotations

import html
import json
import secrets
from http.cookies import SimpleCookie
from urllib.parse import parse_qs

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from webtool.settings import is_loopback

COOKIE_NAME = "drovisio_token"
QUERY_PARAM = "token"
STATE_KEY = "drovisio_access"
FULL, VIEWER = "full", "viewer"
WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})

_EXPLANATION = (
    "This Drovisio web tool is shared on the network and needs its access token. "
    "Open the link that `drovisio serve` printed (it ends with ?token=...), "
    "or send the header 'Authorization: Bearer TOKEN'."
)


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


def _set_access(scope: Scope, level: str) -> None:
    scope.setdefault("state", {})[STATE_KEY] = level


def access_level(request_or_scope) -> str:  # noqa: ANN001 - Request, WebSocket or scope
    """``"full"`` or ``"viewer"`` for a request that passed the middleware (``"full"`` when
    token access is off)."""
    scope = getattr(request_or_scope, "scope", request_or_scope)
    return (scope.get("state") or {}).get(STATE_KEY, FULL)


class TokenAccessMiddleware:
    def __init__(self, app: ASGIApp, token: str | None, viewer_token: str | None = None) -> None:
        self.app = app
        self.token = token
        self.viewer_token = viewer_token

    def _matches(self, candidate: str | None, token: str | None = None) -> bool:
        token = self.token if token is None else token
        return bool(candidate) and bool(token) and secrets.compare_digest(candidate.encode(),
                                                                          token.encode())

    def _viewer_token(self, scope: Scope) -> str | None:
        if self.viewer_token is not None:
            return self.viewer_token
        app = scope.get("app")  # Starlette puts itself here before the middleware stack
        settings = getattr(getattr(app, "state", None), "settings", None)
        return getattr(settings, "viewer_token", None)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket") or self.token is None:
            if scope["type"] in ("http", "websocket"):
                _set_access(scope, FULL)
            await self.app(scope, receive, send)
            return
        client = scope.get("client")
        if client and is_loopback(client[0]):
            _set_access(scope, FULL)
            await self.app(scope, receive, send)
            return

        headers = _headers(scope)
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        from_query = (query.get(QUERY_PARAM) or [None])[0]
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:  # a malformed cookie header is just "no cookie"
            pass
        from_cookie = cookie[COOKIE_NAME].value if COOKIE_NAME in cookie else None
        auth = headers.get("authorization", "")
        from_bearer = auth[7:].strip() if auth.lower().startswith("bearer ") else None

        if self._matches(from_query):
            _set_access(scope, FULL)
            await self.app(scope, receive, self._with_cookie(send, scope))
            return
        if self._matches(from_cookie) or self._matches(from_bearer):
            _set_access(scope, FULL)
            await self.app(scope, receive, send)
            return
        viewer = self._viewer_token(scope)
        if viewer and any(self._matches(c, viewer)
                          for c in (from_query, from_cookie, from_bearer)):
            if scope["type"] == "http" and scope.get("method", "GET").upper() in WRITE_METHODS:
                await self._read_only(send)
                return
            _set_access(scope, VIEWER)
            if self._matches(from_query, viewer):
                send = self._with_cookie(send, scope, viewer)
            await self.app(scope, receive, send)
            return
        await self._refuse(scope, send, headers)

    async def _read_only(self, send: Send) -> None:
        body = json.dumps({"detail": "read-only access",
                           "help": "This link is a viewer link: it can watch, not change. "
                                   "Ask for the full access link printed by `drovisio serve`."
                           }).encode()
        await send({"type": "http.response.start", "status": 403,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode()),
                                (b"cache-control", b"no-store")]})
        await send({"type": "http.response.body", "body": body})

    def _with_cookie(self, send: Send, scope: Scope, token: str | None = None) -> Send:
        if scope["type"] != "http":
            return send
        secure = "; Secure" if scope.get("scheme") == "https" else ""
        value = f"{COOKIE_NAME}={token or self.token}; Path=/; HttpOnly; SameSite=Lax{secure}"

        async def send_with_cookie(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = dict(message)
                message["headers"] = [*message.get("headers", []),
                                      (b"set-cookie", value.encode("latin-1"))]
            await send(message)

        return send_with_cookie

    async def _refuse(self, scope: Scope, send: Send, headers: dict[str, str]) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": "access token required"})
            return
        wants_json = scope.get("path", "").startswith("/api/") or (
            "application/json" in headers.get("accept", "")
            and "text/html" not in headers.get("accept", "")
        )
        if wants_json:
            body = json.dumps({"detail": "access token required", "help": _EXPLANATION}).encode()
            ctype = b"application/json"
        else:
            body = (
                "<!doctype html><html lang=en><meta charset=utf-8>"
                "<meta name=viewport content='width=device-width, initial-scale=1'>"
                "<title>Access token required - Drovisio</title>"
                "<body style='font:20px/1.5 system-ui,sans-serif;max-width:40em;margin:2em auto;"
                "padding:0 1em'><h1>Access token required</h1>"
                f"<p>{html.escape(_EXPLANATION)}</p></body></html>"
            ).encode()
            ctype = b"text/html; charset=utf-8"
        await send({
            "type": "http.response.start",
            "status": 401,
            "headers": [
                (b"content-type", ctype),
                (b"content-length", str(len(body)).encode()),
                (b"www-authenticate", b'Bearer realm="drovisio"'),
                (b"cache-control", b"no-store"),
            ],
        })
        await send({"type": "http.response.body", "body": body})


# --------------------------------------------------------------------------------------------
# What `drovisio serve` prints for phones: links and QR codes
# --------------------------------------------------------------------------------------------


def terminal_qr(text: str) -> str:
    """A QR code of ``text`` drawn with block characters for a terminal (needs ``segno``);
    empty when segno is missing."""
    try:
        import segno
    except ImportError:  # pragma: no cover - segno is a dependency
        return ""
    import io

    qr = segno.make(text, error="m")
    buf = io.StringIO()
    qr.terminal(out=buf, compact=True, border=2)
    return buf.getvalue()


def access_lines(base_url: str, token: str | None, viewer_token: str | None,
                 qr: bool = True) -> list[str]:
    """Lines for the terminal: the full-access and the read-only link for one base URL (e.g.
    ``http://192.168.1.20:8080/``), each with its QR code."""
    lines: list[str] = []
    for label, tok, page in (("full access (calibrate, design, control)", token, ""),
                             ("view only (watch the live view)", viewer_token, "live")):
        if not tok:
            continue
        url = f"{base_url.rstrip('/')}/{page}?{QUERY_PARAM}={tok}"
        lines.append(f"  {label}: {url}")
        if qr:
            lines.extend("  " + row for row in terminal_qr(url).rstrip("\n").splitlines())
    return lines
