"""The study API's response models (``/api/study``)."""

from __future__ import annotations

from webtool.schemas import Answer, Json

__all__ = ["StudyProgress", "StudyReports"]


class StudyReports(Answer):
    """The reports of the data folder (name, protocol, frames, seconds), newest first, and
    the folders that are not reports (with why)."""

    folder: str
    reports: list[dict[str, Json]]
    skipped: list[dict[str, Json]]


class StudyProgress(Answer):
    """The study started from the page: running, fraction done, message, error, report, and
    whether it was cancelled (the web tool stopped during it: no report)."""

    running: bool
    fraction: float
    message: str
    error: str | None
    report: str | None
    cancelled: bool = False
