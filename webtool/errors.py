"""The web tool's errors and their one handler: every domain error becomes ``{"detail": ...}``
with a plain-words message and its status; nothing a user can cause gives a 500.

* :class:`ServiceError` — a request a service cannot do now (``status``: 404 nothing there,
  409 not possible now, 413 too big, 422 bad input, 503 not available, 507 disk full);
* :class:`~drovisio.errors.InputError` (bad files and values, e.g. a layout) → 422;
* :class:`~drovisio.errors.WriteError` (a file could not be written; nothing was lost) → 507;
* :class:`~drovisio.designer.model.DesignError` (an impossible design edit) → 422;
* a request body that does not fit its schema → 422, one line naming the field; one that
  cannot even be parsed (not JSON, not UTF-8, nested too deeply, a number of thousands of
  digits) → 422, one line naming the body;
* an OS or Python limit a request reached (a name over 255 bytes, a NUL byte in a path, an
  integer of thousands of digits) → 422, one line;
* anything else is a bug: 500 with one line, the traceback in the server log.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException
from starlette.responses import Response

from drovisio.designer.model import DesignError
from drovisio.errors import InputError, WriteError, limit_message, one_line
from webtool.responses import NO_STORE, JSONResponse

__all__ = ["BadInput", "Conflict", "DiskFull", "Forbidden", "NotFound", "ServiceError", "TooBig",
           "Unavailable", "install_error_handlers"]

log = logging.getLogger("webtool")


class ServiceError(Exception):
    """A request that cannot be done now; the message is meant for the person at the page.

    Services raise one of the kinds below; its class says the HTTP status (``status``), so
    that the mapping from domain errors to HTTP lives here only. ``ServiceError(message,
    status)`` gives another status where no kind fits.
    """

    status = 409

    def __init__(self, message: str, status: int | None = None) -> None:
        super().__init__(message)
        if status is not None:
            self.status = status


class Forbidden(ServiceError):
    """Not allowed with this access (a viewer link)."""

    status = 403


class NotFound(ServiceError):
    """Nothing there (yet): no such view, report, recording; not solved yet."""

    status = 404


class Conflict(ServiceError):
    """Not possible now (the state of the page does not allow it)."""

    status = 409


class TooBig(ServiceError):
    """An upload over its limit."""

    status = 413


class BadInput(ServiceError):
    """A request whose values cannot be used."""

    status = 422


class Unavailable(ServiceError):
    """Not available now (no frame yet, a 3D view that could not start)."""

    status = 503


class DiskFull(ServiceError):
    """Something could not be saved (nothing was lost)."""

    status = 507


def _answer(status: int, message: str) -> JSONResponse:
    return JSONResponse({"detail": one_line(message, 800)}, status_code=status,
                        headers=NO_STORE)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors()[:3]:
        if err.get("type") == "json_invalid":
            why = (err.get("ctx") or {}).get("error", "")
            pos = (err.get("loc") or ("body", 0))[-1]
            parts.append(f"body: not valid JSON at character {pos}: {why}")
            continue
        loc = [str(x) for x in err.get("loc", ()) if x not in ("body", "query", "path")]
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        parts.append(f"{'.'.join(loc) or 'body'}: {msg}")
    return "; ".join(parts) or "invalid request"


def _unparsed_body_message(cause: BaseException) -> str:
    """One line for a request body the parser gave up on (FastAPI answers those with a bare
    400 "There was an error parsing the body"), from what the parser raised."""
    if isinstance(cause, RecursionError):
        return "body: nested too deeply; send a plain JSON object"
    if isinstance(cause, UnicodeDecodeError):
        return f"body: not UTF-8 text (byte {cause.start}); send JSON in UTF-8"
    limit = limit_message(cause)
    if limit is not None:
        return f"body: {limit}"
    return f"body: cannot be read ({type(cause).__name__}); send JSON"


def install_error_handlers(app: FastAPI) -> None:
    """Register the one handler of every error the tool knows."""
    @app.exception_handler(ServiceError)
    async def _service(request: Request, exc: ServiceError) -> JSONResponse:
        return _answer(exc.status, str(exc))

    @app.exception_handler(InputError)
    async def _input(request: Request, exc: InputError) -> JSONResponse:
        return _answer(422, str(exc))

    @app.exception_handler(DesignError)
    async def _design(request: Request, exc: DesignError) -> JSONResponse:
        return _answer(422, str(exc))

    @app.exception_handler(WriteError)
    async def _write(request: Request, exc: WriteError) -> JSONResponse:
        return _answer(507, str(exc))

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> Response:
        if exc.status_code == 400 and exc.__cause__ is not None:  # the body did not parse
            return _answer(422, _unparsed_body_message(exc.__cause__))
        return await http_exception_handler(request, exc)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _answer(422, _validation_message(exc))

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        limit = limit_message(exc)
        if limit is not None:  # an OS or Python limit the request reached: bad input
            return _answer(413 if isinstance(exc, MemoryError) else 422, limit)
        log.error("internal error on %s %s", request.method, request.url.path, exc_info=exc)
        return _answer(500, f"internal error ({type(exc).__name__}); the server log has the "
                            "details")
