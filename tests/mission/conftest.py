"""Fixtures of the mission tests: the shipped scenario and small parts of it (fast runs)."""

from __future__ import annotations

import pytest

from drovisio.mission.scenario import load_scenario, shipped_scenario


@pytest.fixture(scope="session")
def wall():
    """The shipped scenario: a two-course wall of nine dricks."""
    return load_scenario(shipped_scenario())


@pytest.fixture(scope="session")
def small(wall):
    """Three bricks: two in course 1 and the one straddling them (every kind of slot)."""
    return wall.subset(["b1", "b2", "b6"])
