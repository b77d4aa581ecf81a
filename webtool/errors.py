"""The web tool's errors and their one handler: every domain error becomes ``{"detail": ...}``
with a plain-words message and its status; nothing a user can cause gives a 500.

* :class:`ServiceError` — a request a service cannot do now (``status``: 404 nothing there,
  409 not possible now, 413 too big, 422 bad input, 503 not available, 507 disk full);
* :class:`~drovisio.errors.InputError` (bad files and values, e.g. a layout) → 422;
* :class:`~drovisio.errors.WriteError` (a file could not be written; nothing was lost) → 507;
* :class:`~drovisio.designer.model.DesignError` (an impossible design edit) → 422;
* a request body that does not fit its schema → 422, one line naming the field;
* an OS or Python limit a request reached (a name over 255 bytes, a NUL byte in a path, an
  integer of thousands of digits) → 422, one line;
* anything else is a bug: 500 with one line, the traceback in the server log.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError

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
        loc = [str(x) for x in err.get("loc", ()) if x not in ("body", "query", "path")]
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        parts.append(f"{'.'.join(loc) or 'body'}: {msg}")
    return "; ".join(parts) or "invalid request"


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
