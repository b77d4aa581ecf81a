"""What every command line of Drovisio shares: argparse value types and help text.

The ``drovisio`` commands (:mod:`drovisio.commands`) and the benchmarks (:mod:`drovisio.bench`)
both parse numbers through these types, so that a bad value is refused in one line naming the
range it must be in (:mod:`drovisio.bounds`). Nothing here loads OpenCV or numpy: ``drovisio
--help`` imports it.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable
from dataclasses import dataclass

from drovisio.bounds import (
    MAX_SUPERSAMPLING,
    MOUNT_OFFSET_MAX_M,
    number,
    parse_whole,
    whole,
)
from drovisio.errors import one_line

__all__ = [
    "Command",
    "board_square",
    "bounded",
    "drone_id",
    "finite_float",
    "mount_offset",
    "nonnegative_float",
    "plain_help",
    "port_number",
    "positive_float",
    "positive_int",
    "seed_number",
    "supersampling",
    "whole_in",
]

PROG = "drovisio"


def positive_int(text: str) -> int:
    """argparse type: a whole number from 1 to a billion (:mod:`drovisio.bounds`)."""
    return whole(1, 10**9)(text)


def finite_float(text: str) -> float:
    """argparse type: a finite number (at most 10⁹ in size)."""
    return number(-1e9, 1e9)(text)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (at most 10⁹)."""
    return number(0.0, 1e9, above=True)(text)


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number ≥ 0 (at most 10⁹)."""
    return number(0.0, 1e9)(text)


def mount_offset(text: str) -> float:
    """argparse type: one coordinate of the camera's offset, metres, within the bound every
    mount file is held to (:data:`drovisio.bounds.MOUNT_OFFSET_MAX_M`)."""
    return number(-MOUNT_OFFSET_MAX_M, MOUNT_OFFSET_MAX_M, unit="m")(text)


def seed_number(text: str) -> int:
    """argparse type: a random seed, 0 to 2³²−1 (what numpy's generators take)."""
    return whole(0, 2**32 - 1)(text)


def supersampling(text: str) -> int:
    """argparse type: the renderer's samples per pixel and axis, 1 to
    :data:`drovisio.bounds.MAX_SUPERSAMPLING` (its memory grows with the square)."""
    return whole(1, MAX_SUPERSAMPLING)(text)


def board_square(text: str) -> float:
    """argparse type: a board square's side, metres (above 0, at most 1 m)."""
    return number(0.0, 1.0, above=True, unit="m")(text)


def whole_in(lo: int, hi: int) -> Callable[[str], int]:
    """argparse type: a whole number in ``lo..hi``."""
    return whole(lo, hi)


def bounded(lo: float, hi: float, above: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number in ``[lo, hi]`` (``above``: ``lo`` excluded)."""
    return number(lo, hi, above=above)


def drone_id(text: str) -> str:
    """argparse type: a drone id usable in ROS names and Zenoh keys."""
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,31}", text):
        raise argparse.ArgumentTypeError(
            f"{text!r}: a letter, then letters, digits or _ (at most 32), e.g. drone1")
    return text


def port_number(text: str) -> int:
    """argparse type: a TCP port, 1 to 65535."""
    try:
        return parse_whole(text, 1, 65535)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{one_line(text, 40)} is not a port (1 to 65535)") \
            from None


def plain_help(doc: str | None) -> str:
    """A docstring as a person reads it in a terminal: reST's markup (````code````,
    ``**bold**``, ``:role:`~x.y```) taken out, the words kept."""
    text = doc or ""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], text)
    text = text.replace("``", "").replace("**", "")
    return text


@dataclass(frozen=True)
class Command:
    """One ``drovisio`` command: its help (the contract of DESIGN.md), its arguments and
    where its code lives."""

    name: str
    summary: str
    """One line, shown in ``drovisio --help``."""
    description: str
    """A paragraph, shown in ``drovisio NAME --help``."""
    example: str
    """Shown under "Example:" in ``drovisio NAME --help``."""
    add_arguments: Callable[[argparse.ArgumentParser], None]
    target: str = ""
    """``"module:function"``; default ``drovisio.commands.<name>:run``."""
    spelled: str = ""
    """How users type it, when not its name (``calibrate board``)."""

    @property
    def entry_point(self) -> str:
        return self.target or f"{PROG}.commands.{self.name}:run"
