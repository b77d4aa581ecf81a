"""What the calibration page tells the person holding the board, in plain words: what the
last frame means, why an image was not kept, and what to do next."""

from __future__ import annotations

from typing import Any

from drovisio.calibration.board import BoardSpec
from drovisio.calibration.session import FrameResult

__all__ = ["frame_feedback", "next_step", "plain_reason", "saved_views"]


def saved_views(n: int) -> str:
    """"The N views captured so far are saved." (empty with none)."""
    if n == 0:
        return ""
    return f"The {n} view{'s' if n != 1 else ''} captured so far {'are' if n != 1 else 'is'} saved."


def _not_detected_message(fr: FrameResult) -> str:
    if any("image size" in r for r in fr.reasons):
        return ("The camera's image size differs from this session's: start a new session "
                "(below) to calibrate this camera.")
    return "No board in view: show the whole chessboard to the camera."


def _detected_message(fr: FrameResult, auto: bool) -> str:
    failed = [g.name for g in fr.gates if not g.ok]
    n = fr.detection.n if fr.detection is not None else 0
    if "size" in failed:
        return "The board looks too small: bring it closer to the camera."
    if "sharpness" in failed:
        return "The image is blurred: hold the board steady (or add light)."
    if "still" in failed:
        return "Board found. Hold it still…"
    if "novel" in failed:
        return ("You already have a view like this one: move the board to the place shown in "
                "yellow.")
    if not auto:
        return f"Board found ({n} corners). Press Capture to keep this view."
    return f"Board found ({n} corners)."


def frame_feedback(fr: FrameResult | None, auto: bool) -> dict[str, Any]:
    """What the last frame means, for the page: ``detected``, ``kept``, ``message``,
    ``detail`` (and ``view_id`` once kept)."""
    if fr is None:
        return {"detected": False, "kept": False, "message": "Waiting for the camera…",
                "detail": ""}
    detail = "; ".join(fr.reasons)
    if fr.kept:
        return {"detected": True, "kept": True, "view_id": fr.view_id,
                "message": f"Captured view #{fr.view_id}. Move the board to the next place.",
                "detail": ""}
    if fr.detection is None:
        return {"detected": False, "kept": False, "message": _not_detected_message(fr),
                "detail": detail}
    return {"detected": True, "kept": False, "message": _detected_message(fr, auto),
            "detail": detail}


def plain_reason(fr: FrameResult, board: BoardSpec) -> str:
    """Why an uploaded image was not kept."""
    if fr.detection is None:
        if fr.reasons and "image size" in fr.reasons[0]:
            return fr.reasons[0]
        return (f"no board found (looking for a chessboard with {board.cols}×{board.rows} "
                f"inner corners, i.e. {board.cols + 1}×{board.rows + 1} squares, fully "
                "visible)")
    return "; ".join(fr.reasons) or "not usable"


def next_step(*, disconnected: bool, views: int, good: bool, show_result: bool,
              suggestion: dict[str, Any]) -> str:
    """The page's "what next" sentence.

    Args:
        disconnected: The camera is lost (retrying).
        views: Kept views.
        good: The verdict is good and the result is of the current views.
        show_result: The result is shown (Solve was pressed).
        suggestion: The next-pose hint (its ``sentence``).
    """
    if disconnected:
        return ("The camera is disconnected. Check its cable or connection; Drovisio keeps "
                "trying. " + saved_views(views)).strip()
    if views == 0:
        return ("Hold the printed chessboard in front of the camera, the whole board "
                "visible and still.")
    if good:
        return ("The calibration is good: download the camera file, or press “Use this "
                "calibration”." if show_result
                else "The calibration is good. Press Solve to see the result.")
    return str(suggestion.get("sentence", ""))
