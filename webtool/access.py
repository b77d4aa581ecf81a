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

_EXPLANATION = (
    "This Drovisio web tool is shared on the network and needs its access token. "
    "Open the link that `drovisio serve` printed (it ends with ?token=...), "
    "or send the header 'Authorization: Bearer TOKEN'."
)


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


class TokenAccessMiddleware:
    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self.token = token

    def _matches(self, candidate: str | None) -> bool:
        return bool(candidate) and secrets.compare_digest(candidate.encode(), self.token.encode())

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket") or self.token is None:
            await self.app(scope, receive, send)
            return
        client = scope.get("client")
        if client and is_loopback(client[0]):
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
            await self.app(scope, receive, self._with_cookie(send, scope))
            return
        if self._matches(from_cookie) or self._matches(from_bearer):
            await self.app(scope, receive, send)
            return
        await self._refuse(scope, send, headers)

    def _with_cookie(self, send: Send, scope: Scope) -> Send:
        if scope["type"] != "http":
            return send
        secure = "; Secure" if scope.get("scheme") == "https" else ""
        value = f"{COOKIE_NAME}={self.token}; Path=/; HttpOnly; SameSite=Lax{secure}"

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
