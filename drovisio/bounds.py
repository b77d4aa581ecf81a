"""One helper for every number that comes from outside: command-line arguments (the benches'
included) and numbers read from files (protocols, mount files, board specs).

A number is refused in one line, naming where it came from and the range it must be in,
when it is not a number, not finite, out of its range, or written with more digits than any
sensible value has (Python itself refuses to convert integers of more than 4,300 digits, and a
value of 10^20 views would run for ever): ``--views: 1e20 is not in 1..1000; give ...``.

* :func:`whole` and :func:`number` make argparse ``type=`` functions;
* :func:`check_whole` and :func:`check_number` check a value read from a file and raise
  :class:`~drovisio.errors.InputError` naming the file's field.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import NoReturn

from drovisio.errors import LIMITS, InputError, one_line

__all__ = ["CAMERA_TILT_MAX_DEG", "MAX_CAMERA_INDEX", "MAX_SUPERSAMPLING", "ArgumentParser", "MOUNT_OFFSET_MAX_M", "check_number", "check_whole", "number", "parse_number", "parse_whole", "whole"]

MOUNT_OFFSET_MAX_M = 10.0
"""Largest camera offset from the body origin, metres, in each axis: one bound for the mount
file, ``calibrate mount --offset`` and the mount page (a larger one is a unit mistake)."""

CAMERA_TILT_MAX_DEG = 90.0
"""Largest tilt of a mission's camera from straight down, forward or back (a scenario's
``tilt_deg``, ``mission landing --tilt``): beyond it the camera looks above the horizon and
never sees a brick on the ground."""

MAX_CAMERA_INDEX = 255
"""Highest camera index (``--source N``, ``/dev/videoN``): Linux numbers its video devices
below 256."""

MAX_SUPERSAMPLING = 8
"""Most renderer samples per pixel and axis (``--ss``): memory grows with its square (at 64 a
640x480 render asks for tens of GiB); 8 is far past where edges stop changing."""


class ArgumentParser(argparse.ArgumentParser):
    """The command line's parser (every command's and every bench's): a usage error is one
    line, like every other error, that quotes the argument it could not use cut short
    (argparse echoes it whole: a 5,000-digit or multi-line argument made an error of pages)
    and points to the command's help instead of repeating its usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {one_line(message, 400)} (see {self.prog} --help)\n")


def _range(lo: float | None, hi: float | None, unit: str = "") -> str:
    u = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        return f"from {lo:g} to {hi:g}{u}"
    if lo is not None:
        return f"{lo:g}{u} or more"
    return f"{hi:g}{u} or less"


def parse_whole(text: object, lo: int | None = None, hi: int | None = None) -> int:
    """A whole number in ``lo..hi`` from ``text`` (a string or a number).

    Raises:
        ValueError: with a plain-words reason (the callers add where it came from).
    """
    if isinstance(text, bool):
        raise ValueError(f"{text} is not a whole number")
    if isinstance(text, int):
        v = text
    elif isinstance(text, float):
        if not math.isfinite(text) or text != int(text):
            raise ValueError(f"{text} is not a whole number")
        v = int(text)
    else:
        s = str(text).strip()
        if len(s.lstrip("+-")) > LIMITS.max_digits:
            raise ValueError(f"{one_line(s, 24)} has {len(s)} digits; give at most "
                             f"{LIMITS.max_digits}")
        try:
            v = int(s)
        except ValueError:
            raise ValueError(f"{one_line(s, 40)!r} is not a whole number") from None
    if abs(v) > 10 ** LIMITS.max_digits:
        raise ValueError(f"a number of {len(str(abs(v)))} digits is not sensible here")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError(f"{v} is out of range: give a whole number {_range(lo, hi)}")
    return v


def parse_number(text: object, lo: float | None = None, hi: float | None = None, *,
                 above: bool = False, unit: str = "") -> float:
    """A finite number in ``[lo, hi]`` (``above``: strictly above ``lo``) from ``text``.

    Raises:
        ValueError: with a plain-words reason.
    """
    if isinstance(text, bool):
        raise ValueError(f"{text} is not a number")
    if isinstance(text, str):
        s = text.strip()
        if len(s) > 64:
            raise ValueError(f"{one_line(s, 24)} is {len(s)} characters long; not a number "
                             "this tool can use")
        try:
            v = float(s)
        except ValueError:
            raise ValueError(f"{one_line(s, 40)!r} is not a number") from None
    else:
        try:
            v = float(text)  # type: ignore[arg-type]
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{one_line(text, 40)!r} is not a number") from None
    bounded = lo is not None or hi is not None
    rng = "" if not bounded else (
        f"above {lo:g}" + (f" and at most {hi:g}" if hi is not None else "")
        + (f" {unit}" if unit else "") if above and lo is not None else _range(lo, hi, unit))
    if not math.isfinite(v):
        raise ValueError(f"{v} is not a finite number" + (f"; give a number {rng}" if bounded
                                                           else ""))
    if (lo is not None and (v < lo or (above and v == lo))) or (hi is not None and v > hi):
        raise ValueError(f"{v:g} is out of range: give a number {rng}")
    return v


def whole(lo: int | None = 1, hi: int | None = None) -> Callable[[str], int]:
    """argparse ``type=``: a whole number in ``lo..hi``."""
    def parse(text: str) -> int:
        try:
            return parse_whole(text, lo, hi)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = "whole number"
    return parse


def number(lo: float | None = None, hi: float | None = None, *,
           above: bool = False, unit: str = "") -> Callable[[str], float]:
    """argparse ``type=``: a finite number in ``[lo, hi]`` (``above``: ``lo`` excluded)."""
    def parse(text: str) -> float:
        try:
            return parse_number(text, lo, hi, above=above, unit=unit)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = "number"
    return parse


def check_whole(value: object, where: str, lo: int | None = None,
                hi: int | None = None) -> int:
    """A whole number read from a file; ``where`` is ``FILE: FIELD``.

    Raises:
        InputError: ``where: reason``.
    """
    try:
        return parse_whole(value, lo, hi)
    except ValueError as e:
        raise InputError(f"{where}: {e}") from None


def check_number(value: object, where: str, lo: float | None = None, hi: float | None = None,
                 *, above: bool = False, unit: str = "") -> float:
    """A finite number read from a file; ``where`` is ``FILE: FIELD``.

    Raises:
        InputError: ``where: reason``.
    """
    try:
        return parse_number(value, lo, hi, above=above, unit=unit)
    except ValueError as e:
        raise InputError(f"{where}: {e}") from None
