"""The parts of the calibration page's state (``GET /api/calibration/state``): the session,
the camera, the kept views, the coverage, the progress towards a good calibration and the
camera file in use; each a JSON-ready ``dict``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drovisio.calibration.coverage import Coverage
from drovisio.calibration.printout import print_square_mm
from drovisio.calibration.session import CalibrationSession
from drovisio.calibration.verdict import Verdict
from webtool.calibration.camera import CameraStatus

__all__ = ["camera_json", "coverage_json", "in_use_json", "print_squares", "progress_json",
           "session_json", "view_rows"]


def print_squares(board: Any) -> dict[str, float]:
    """The square each paper's printout of the board has (the PDF prints exactly this), mm."""
    return {paper: print_square_mm(board, paper) for paper in ("A4", "A3", "Letter")}


def session_json(sess: CalibrationSession, session_id: str, folder: Path, created: float,
                 source_label: str, source: str | None, *, square_measured: bool
                 ) -> dict[str, Any]:
    """The session: its id and folder, the board (square in mm), where the frames come from.

    Args:
        sess: The session.
        session_id: Its id (its folder's name).
        folder: Its folder.
        created: When it was started (UNIX time).
        source_label: What the camera's reader calls itself ("" before the first frame).
        source: The server's ``--source`` (None: the sample session).
        square_measured: The square size was measured on the print.
    """
    return {"id": session_id, "folder": str(folder),
            "board": sess.board.spec(), "square_mm": round(sess.board.square * 1000, 3),
            "cols": sess.board.cols, "rows": sess.board.rows,
            "square_measured": square_measured,
            "print_square_mm": print_squares(sess.board),
            "created": created, "source": source_label or (
                "sample session (no camera)" if source is None else f"camera {source}"),
            "sample": source is None}


def camera_json(cam: CameraStatus, frame_seq: int, image_size: tuple[int, int] | None
                ) -> dict[str, Any]:
    """The camera's state, its message, the number of the latest frame and the image size
    (width, height) in pixels (the session's, else the camera's, else 640×480)."""
    return {"state": cam.state, "message": cam.message, "since": cam.since,
            "frame_seq": frame_seq, "image_size": list(image_size or (640, 480))}


def view_rows(views: list[Any], result: Any, session_id: str) -> list[dict[str, Any]]:
    """One row per kept view: corners, where it came from, its fit (px) in the latest solve,
    the solver's note, its thumbnail's URL."""
    fits = {f.name: f for f in result.per_view} if result is not None else {}
    rejected = {r["file"]: r["reason"] for r in (result.rejected if result is not None else [])}
    rows = []
    for v in views:
        f = fits.get(v.name)
        rows.append({
            "id": v.id, "name": v.name, "corners": v.detection.n,
            "origin": "upload" if v.name.startswith("upload-") else "camera",
            "rms_px": None if f is None else round(float(f.rms_px), 3),
            "max_px": None if f is None else round(float(f.max_px), 3),
            "note": rejected.get(v.name, ""),
            "thumb": f"/api/calibration/views/{v.id}/thumb.jpg?s={session_id}",
        })
    return rows


def coverage_json(cov: Coverage) -> dict[str, Any]:
    """How much of the image the board has covered (grid cells, fraction, what is missing)."""
    grid = cov.to_json()
    return {"cols": grid["grid"]["cols"], "rows": grid["grid"]["rows"],
            "covered": grid["grid"]["covered_fraction"],
            "image_covered_fraction": round(cov.covered_fraction, 4),
            "uncovered_regions": cov.uncovered_regions(),
            "distance_spread": grid["distance_spread"],
            "tilt_spread": grid["tilt_spread"]}


def progress_json(sess: CalibrationSession, views: int, cov: Coverage, verdict: Verdict,
                  good: bool, nxt: str) -> dict[str, Any]:
    """Progress towards a good calibration: views, coverage, uncertainty (p95, px), the
    verdict's reasons and what to do next."""
    res = sess.result
    rules = sess.config.verdict
    p95 = res.uncertainty.stats(sess.config.roi)["p95"] if res is not None else None
    return {"views": views, "views_needed": rules.min_views,
            "solve_needs": sess.config.solve.min_views,
            "covered_fraction": round(cov.covered_fraction, 4),
            "p95_px": None if p95 is None else round(p95, 4),
            "p95_limit_px": rules.max_uncertainty_p95_px,
            "ok": good, "reasons": list(verdict.reasons), "next": nxt}


def in_use_json(used_camera: str | None, camera: Any) -> dict[str, Any]:
    """The server's camera file, and whether it is this session's result."""
    in_use = bool(used_camera) and str(camera or "") == used_camera
    return {"camera_file": str(camera) if camera else None, "this_session": in_use}
