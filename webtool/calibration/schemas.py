"""The calibration API's request bodies and response models (``/api/calibration``)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from webtool.schemas import Answer, Body, Json

__all__ = ["AutoBody", "AutoCapture", "CalibrationReport", "CalibrationState", "Captured",
           "InUse", "LensBody", "LensSet", "NewSession", "SessionBody", "SolveRequested",
           "SquareBody", "SquareSet", "UploadResult", "ViewDeleted"]


# ------------------------------------------------------------------------------ requests
class AutoBody(Body):
    on: bool


class LensBody(Body):
    model: Literal["auto", "plumb_bob", "rational", "thin_prism", "tilted", "fisheye"]


class SquareBody(Body):
    square_m: Annotated[float, Field(gt=0, le=1)]   # metres, as measured on the print


class SessionBody(Body):
    board: Annotated[str, Field(min_length=1, max_length=80)] | None = None
    square_m: Annotated[float, Field(gt=0)] | None = None   # metres; the board checks more


# ----------------------------------------------------------------------------- answers
class CalibrationState(Answer):
    """Everything the page shows."""

    session: dict[str, Json]
    """id, folder, board, square_mm, cols, rows, square_measured, print_square_mm, created,
    source, sample"""
    camera: dict[str, Json]
    """state (stopped, starting, ok, disconnected), message, since, frame_seq, image_size"""
    auto_capture: bool
    lens: dict[str, Json]
    feedback: dict[str, Json]
    generation: int
    views: list[dict[str, Json]]
    coverage: dict[str, Json]
    suggestion: dict[str, Json]
    progress: dict[str, Json]
    solve: dict[str, Json]
    in_use: dict[str, Json]


class AutoCapture(Answer):
    auto_capture: bool


class Captured(Answer):
    view_id: int | None
    message: str


class ViewDeleted(Answer):
    deleted: int
    views: int
    """views left"""


class UploadResult(Answer):
    summary: str
    kept: int
    files: list[dict[str, Json] | None]
    """per file: file, ok, message (view_id when kept, skipped when not an image)"""
    hint: str | None
    """another board size visible in the pictures, when no board was found"""


class SquareSet(Answer):
    square_mm: float
    square_measured: bool


class LensSet(Answer):
    lens_model: str


class SolveRequested(Answer):
    solving: bool
    has_result: bool


class CalibrationReport(Answer):
    """The report (parameters ± σ, RMS, uncertainty, verdict…; see
    :func:`drovisio.calibration.report.build_report`) and this session's id."""

    current: bool
    session_id: str
    result_seq: int


class InUse(Answer):
    camera_file: str
    message: str


class NewSession(Answer):
    session: str
    folder: str
    board: str
