"""The errors a user can do something about, and the limits that keep hostile input bounded.

Every reader of outside input (camera, layout, mount, scenario, gravity files, images, videos,
web bodies) raises an :class:`InputError` whose message is one line of the form
``FILE: FIELD: what is wrong and what to do``; the command line prints it as
``drovisio COMMAND: <message>`` and exits with status 2, the web tool answers it as 422. Errors
of the machine rather than of the input (a full disk) are :class:`WriteError`; anything else is
a bug, reported once by the top-level handler with a path to the full traceback.
"""

from __future__ import annotations

import os
import reprlib

__all__ = [
    "InputError",
    "Limits",
    "WriteError",
    "LIMITS",
    "limit_message",
    "one_line",
]


class InputError(ValueError):
    """Input that cannot be used; the message names the file, the field and the fix."""

    status = 422
    """HTTP status when a web route meets it."""


class WriteError(OSError):
    """A file could not be written (full disk, no permission); nothing already saved was
    replaced. The message names the file and what to do."""

    status = 507

    def __init__(self, message: str, code: int = 0) -> None:
        super().__init__(message)
        self.errno = code


def one_line(text: object, limit: int = 400) -> str:
    """``text`` folded onto one line and cut to ``limit`` characters (error messages quote
    parts of hostile files; they must stay short)."""
    if not isinstance(text, str) and isinstance(text, (list, tuple, dict, set)):
        # a container from a hostile file is quoted by its first items only: its whole text
        # may be of billions of values (YAML aliases) or hold itself
        text = _SHORT_REPR.repr(text)
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 1] + "…"


_SHORT_REPR = reprlib.Repr()
_SHORT_REPR.maxlevel = 3
_SHORT_REPR.maxlist = _SHORT_REPR.maxtuple = _SHORT_REPR.maxdict = _SHORT_REPR.maxset = 6


class Limits:
    """Bounds on what outside input may ask of the machine (overridable by environment for
    the rare user who needs more).

    Attributes:
        max_image_pixels: Largest image (width × height) decoded; a header claiming more is
            refused before any pixel is allocated (``DROVISIO_MAX_IMAGE_MPX``, megapixels).
        max_image_side: Largest image width or height accepted from a camera file or header.
        max_file_bytes: Largest camera, layout, mount, scenario or gravity file read.
        max_json_depth: Deepest nesting of JSON/YAML objects accepted.
        max_yaml_aliases: Most YAML alias references in one document (alias bombs).
        max_yaml_expanded: Most values the aliases of one YAML document may add once
            expanded (a hundred aliases of aliases name billions).
        max_markers: Most markers in one layout.
        max_body_bytes: Largest JSON body a web route reads.
    """

    def __init__(self) -> None:
        mpx = _env_float("DROVISIO_MAX_IMAGE_MPX", 50.0)
        self.max_image_pixels = int(mpx * 1e6)
        self.max_image_side = 20000
        self.max_file_bytes = 16 * 1024 * 1024
        self.max_json_depth = 32
        self.max_yaml_aliases = 100
        self.max_yaml_expanded = 100_000
        self.max_markers = 200
        self.max_body_bytes = 1024 * 1024
        self.max_work_bytes = int(_env_float("DROVISIO_MAX_WORK_MIB",
                                             _half_the_memory_mib()) * 2**20)
        """Most memory one render may take (estimated before it starts): half this machine's
        memory by default."""
        self.max_work_samples = int(_env_float("DROVISIO_MAX_WORK_GSAMPLES", 100.0) * 1e9)
        """Most pixel samples one job (a study protocol) may render and detect in all,
        estimated before it starts: 100 G by default, about 30 times the full default
        study."""
        self.max_digits = 30
        """Most digits of an integer read from an argument or a file (Python refuses 4,300)."""
        self.connect_timeout_s = _env_float("DROVISIO_CONNECT_TIMEOUT_S", 5.0)
        """Deadline of every network connect made at start-up (a silent peer)."""


def _half_the_memory_mib() -> float:
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**21
    except (ValueError, OSError, AttributeError):  # not a POSIX system
        return 2048.0


def _env_float(name: str, default: float) -> float:
    try:
        v = float(os.environ.get(name, default))
    except ValueError:
        return default
    return v if v > 0 and v == v and v != float("inf") else default


LIMITS = Limits()


def limit_message(exc: BaseException) -> str | None:
    """One line for an operating-system or Python limit that a hostile input reached (a name
    over 255 bytes, a NUL byte in a path, an integer of thousands of digits, memory), or None
    when ``exc`` is not one of those. The command line answers them with exit 2 and the web
    tool with 422, like any bad input: they are never internal errors."""
    import errno

    if isinstance(exc, MemoryError):
        return ("not enough memory for this input; give a smaller one (or raise "
                "DROVISIO_MAX_WORK_MIB on a machine with more)")
    if isinstance(exc, OSError) and not isinstance(exc, WriteError):
        name = f"{exc.filename}: " if exc.filename is not None else ""
        name = one_line(name, 160)
        if exc.errno == errno.ENAMETOOLONG:
            return (f"{name}the name is too long for the file system (at most 255 bytes a "
                    "name, 4096 a path); choose a shorter one")
        if exc.errno == errno.ELOOP:
            return f"{name}too many symbolic links; give the file itself"
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return f"{name}the disk is full; free some space and try again"
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            return f"{name}not allowed ({exc.strerror}); choose another file or folder"
        return None
    if isinstance(exc, ValueError) and not isinstance(exc, InputError):
        text = str(exc)
        if "embedded null" in text or "null character" in text:
            return "a path contains a NUL byte; give a real file name"
        if "integer string conversion" in text or "digits" in text and "limit" in text:
            return ("a number has thousands of digits; give a number of at most "
                    f"{LIMITS.max_digits} digits")
    return None
