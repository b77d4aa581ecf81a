"""Who may use the web tool: the page's own origin, the hosts it was started for, and tokens.

One ASGI middleware (:class:`AccessMiddleware`) checks every HTTP request and WebSocket, in
this order:

1. **Host.** The ``Host`` header must be a name this server answers to: an IP address
   literal, ``localhost``, the ``--host`` given, or this machine's own names. Any other name
   is what a DNS-rebinding page sends (its own domain, now pointing at 127.0.0.1): refused
   with 403, unless the request carries a valid token.
2. **Origin.** Every write (POST, PUT, PATCH, DELETE) and every WebSocket from a browser
   carries ``Origin``; it must be the tool's own (the ``Origin``'s scheme is the request's,
   its host:port the ``Host``). A page on any other origin gets 403, **even on loopback** and
   even with a token in a cookie (CSRF). ``Sec-Fetch-Site: cross-site`` (or ``same-site``:
   another port of the same host) is refused too. Programs that send no ``Origin`` (scripts,
   curl) are judged by host and token alone. A GET that starts work (the live pipeline, the
   calibration camera, a 3D view) goes through the same check where that work starts
   (:func:`refuse_other_sites`): an ``<img>`` on another site's page sends no ``Origin``,
   but its browser says ``Sec-Fetch-Site``.
3. **Token.** With ``token=None`` (the default, bound to 127.0.0.1) nothing more is asked.
   Otherwise a loopback client still passes; any other client must present the token: as
   ``?token=...`` (what ``drovisio serve`` prints; a valid one sets an HttpOnly cookie), the
   ``drovisio_token`` cookie, or ``Authorization: Bearer ...``. Without it: 401 with a short
   explanation; a WebSocket is closed before it is accepted.

A second, **read-only viewer token** (``Settings.viewer_token``) lets a person watch — every
page, GET/HEAD request and WebSocket — but not change anything: writes answer 403. Routes see
the access level as ``request.state.drovisio_access`` (:func:`access_level`) and must not take
changes over a WebSocket from a viewer. Tokens never reach the server log
(:func:`redact_tokens` filters uvicorn's access log).

:func:`terminal_qr` and :func:`access_lines` give what ``drovisio serve`` prints for phones.
"""

from __future__ import annotations

import html
import ipaddress
import json
import logging
import re
import secrets
import socket
from http.cookies import SimpleCookie
from urllib.parse import parse_qs, urlsplit

from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drovisio.errors import one_line
from webtool.errors import Forbidden
from webtool.settings import is_loopback

__all__ = [
    "AccessMiddleware",
    "COOKIE_NAME",
    "access_level",
    "access_lines",
    "install_log_redaction",
    "other_site",
    "redact_tokens",
    "refuse_other_sites",
    "terminal_qr",
]

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
    """``"full"`` or ``"viewer"`` for a request that passed the middleware."""
    scope = getattr(request_or_scope, "scope", request_or_scope)
    return (scope.get("state") or {}).get(STATE_KEY, FULL)


def _split_host(value: str) -> tuple[str, str]:
    """(host, port) of a ``Host`` header or an origin's netloc, lowercased, brackets off."""
    v = value.strip().lower()
    if v.startswith("["):
        host, _, rest = v[1:].partition("]")
        return host, rest.removeprefix(":")
    host, _, port = v.rpartition(":") if v.count(":") == 1 else (v, "", "")
    return host, port


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _same_origin(origin: str, host_header: str | None, scheme: str = "http") -> bool:
    """An origin is its scheme, host and port: ``https://127.0.0.1:PORT`` is another
    site than the ``http://`` tool on the same port (a TLS page there is not ours)."""
    if not host_header or origin in ("", "null"):
        return False
    try:
        parts = urlsplit(origin.strip())
    except ValueError:
        return False
    netloc = parts.netloc
    o_scheme = parts.scheme.lower()
    own = {"ws": "http", "wss": "https"}.get(scheme.lower(), scheme.lower())
    if not netloc or o_scheme != own:
        return False
    o_host, o_port = _split_host(netloc)
    h_host, h_port = _split_host(host_header)
    default = "443" if own == "https" else "80"
    return o_host == h_host and (o_port or default) == (h_port or default)


def other_site(scope: Scope) -> str | None:
    """Why a request comes from a page that is not the tool's own, or None: an ``Origin``
    that is not the tool's, or a browser's ``Sec-Fetch-Site`` naming another site. A program
    that sends neither is not a page (judged by host and token alone)."""
    headers = _headers(scope)
    origin = headers.get("origin")
    if origin is not None and not _same_origin(origin, headers.get("host"),
                                               scope.get("scheme", "http")):
        return (f"request from another site ({one_line(origin, 80)}) refused: only the "
                "tool's own pages may change it or start its work")
    if headers.get("sec-fetch-site", "") in ("cross-site", "same-site"):
        return ("request from another site's page refused: only the tool's own pages may "
                "change it or start its work")
    return None


def refuse_other_sites(conn: HTTPConnection) -> None:
    """Where a request starts work (a pipeline, a camera, a 3D view), refuse it from another
    site's page as a write is refused (:func:`other_site`), GET included.

    Raises:
        Forbidden: the request came from another site's page.
    """
    why = other_site(conn.scope)
    if why is not None:
        raise Forbidden(why)


def machine_names() -> set[str]:
    """This machine's own names (a phone on the site's Wi-Fi may use them)."""
    names = {"localhost"}
    try:
        hn = socket.gethostname().lower()
        names |= {hn, f"{hn}.local", socket.getfqdn().lower()}
    except OSError:
        pass
    return {n for n in names if n}


class AccessMiddleware:
    """See the module doc.

    Args:
        app: The ASGI app.
        token: Full-access token (None: token access off).
        viewer_token: Read-only token.
        bind_host: The ``--host`` the server listens on (allowed as a ``Host`` name).
        extra_hosts: More host names to accept (a reverse proxy's name, say).
    """

    def __init__(self, app: ASGIApp, token: str | None, viewer_token: str | None = None,
                 bind_host: str = "127.0.0.1", extra_hosts: tuple[str, ...] = ()) -> None:
        self.app = app
        self.token = token
        self.viewer_token = viewer_token
        self.names = machine_names() | {h.lower().strip("[]") for h in (bind_host, *extra_hosts)
                                        if h}

    # ---------------------------------------------------------------- checks
    def _matches(self, candidate: str | None, token: str | None) -> bool:
        return bool(candidate) and bool(token) and secrets.compare_digest(
            candidate.encode(), token.encode())  # type: ignore[union-attr]

    def _host_ok(self, host_header: str | None) -> bool:
        if not host_header:
            return False
        host, _ = _split_host(host_header)
        return _is_ip(host) or host in self.names

    def _token_level(self, scope: Scope, headers: dict[str, str]) -> tuple[str | None, bool]:
        """(access level the request's token gives or None, the token came in the URL)."""
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        from_query = (query.get(QUERY_PARAM) or [None])[0]
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:  # noqa: BLE001 - a malformed cookie header is just "no cookie"
            pass
        from_cookie = cookie[COOKIE_NAME].value if COOKIE_NAME in cookie else None
        auth = headers.get("authorization", "")
        from_bearer = auth[7:].strip() if auth.lower().startswith("bearer ") else None
        for cand in (from_query, from_cookie, from_bearer):
            if self._matches(cand, self.token):
                return FULL, cand is from_query
        for cand in (from_query, from_cookie, from_bearer):
            if self._matches(cand, self.viewer_token):
                return VIEWER, cand is from_query
        return None, False

    # ---------------------------------------------------------------- ASGI
    def _site_refusal(self, scope: Scope, headers: dict[str, str], level: str | None,
                      writes: bool) -> str | None:
        """Why the request is refused for where it comes from (an unknown Host without a
        token; a write from another site's page), or None."""
        host = headers.get("host")
        if not self._host_ok(host) and level is None:
            return (f"unknown Host {host!r}: this tool answers to its own address only (open "
                    "the address `drovisio serve` printed)")
        return other_site(scope) if writes else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        is_socket = scope["type"] == "websocket"
        method = scope.get("method", "GET").upper()
        writes = is_socket or method in WRITE_METHODS
        level, in_query = self._token_level(scope, headers)

        why = self._site_refusal(scope, headers, level, writes)
        if why is not None:
            await self._forbidden(scope, send, why)
            return

        client = scope.get("client")
        if self.token is None or (client and is_loopback(client[0]) and level is None):
            _set_access(scope, FULL)
            await self.app(scope, receive, send)
            return
        if level is None:
            await self._refuse(scope, send, headers)
            return
        if level == VIEWER and not is_socket and method in WRITE_METHODS:
            await self._read_only(send)
            return
        _set_access(scope, level)
        if in_query:
            send = self._with_cookie(send, scope, self.token if level == FULL
                                     else self.viewer_token)
        await self.app(scope, receive, send)

    # ---------------------------------------------------------------- answers
    @staticmethod
    async def _json(send: Send, status: int, data: dict, extra: list | None = None) -> None:
        body = json.dumps(data).encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode()),
                                (b"cache-control", b"no-store"), *(extra or [])]})
        await send({"type": "http.response.body", "body": body})

    async def _forbidden(self, scope: Scope, send: Send, why: str) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": why[:120]})
            return
        await self._json(send, 403, {"detail": why})

    async def _read_only(self, send: Send) -> None:
        await self._json(send, 403, {
            "detail": "read-only access",
            "help": "This link is a viewer link: it can watch, not change. Ask for the full "
                    "access link printed by `drovisio serve`."})

    def _with_cookie(self, send: Send, scope: Scope, token: str | None) -> Send:
        if scope["type"] != "http" or not token:
            return send
        secure = "; Secure" if scope.get("scheme") == "https" else ""
        value = f"{COOKIE_NAME}={token}; Path=/; HttpOnly; SameSite=Lax{secure}"

        async def send_with_cookie(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = dict(message)
                message["headers"] = [*message.get("headers", []),
                                      (b"set-cookie", value.encode("latin-1"))]
            await send(message)

        return send_with_cookie

    async def _refuse(self, scope: Scope, send: Send, headers: dict[str, str]) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008,
                        "reason": "access token required"})
            return
        wants_json = scope.get("path", "").startswith("/api/") or (
            "application/json" in headers.get("accept", "")
            and "text/html" not in headers.get("accept", ""))
        auth = [(b"www-authenticate", b'Bearer realm="drovisio"')]
        if wants_json:
            await self._json(send, 401, {"detail": "access token required",
                                         "help": _EXPLANATION}, auth)
            return
        body = (
            "<!doctype html><html lang=en><meta charset=utf-8>"
            "<meta name=viewport content='width=device-width, initial-scale=1'>"
            "<title>Access token required - Drovisio</title>"
            "<body style='font:20px/1.5 system-ui,sans-serif;max-width:40em;margin:2em auto;"
            "padding:0 1em'><h1>Access token required</h1>"
            f"<p>{html.escape(_EXPLANATION)}</p></body></html>"
        ).encode()
        await send({"type": "http.response.start", "status": 401,
                    "headers": [(b"content-type", b"text/html; charset=utf-8"),
                                (b"content-length", str(len(body)).encode()),
                                (b"cache-control", b"no-store"), *auth]})
        await send({"type": "http.response.body", "body": body})


# --------------------------------------------------------------------------------------------
# Tokens stay out of the logs
# --------------------------------------------------------------------------------------------

_TOKEN_RE = re.compile(r"(token=)[^&\s\"']+", re.IGNORECASE)


def redact_tokens(text: str) -> str:
    """``...?token=SECRET&x=1`` → ``...?token=***&x=1``."""
    return _TOKEN_RE.sub(r"\1***", text)


class _RedactFilter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if record.args:
            record.args = tuple(redact_tokens(a) if isinstance(a, str) else a
                                for a in (record.args if isinstance(record.args, tuple)
                                          else (record.args,)))
        if isinstance(record.msg, str):
            record.msg = redact_tokens(record.msg)
        return True


def install_log_redaction() -> None:
    """Filter uvicorn's access and error logs (request lines carry the query string)."""
    for name in ("uvicorn.access", "uvicorn.error", "uvicorn"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, _RedactFilter) for f in logger.filters):
            logger.addFilter(_RedactFilter())


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
    import io  # only for the terminal's QR codes

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
