"""Camera calibration that judges by projection uncertainty, not by RMS.

One stage per module:

* :mod:`.board` — board specs (``chessboard:9x6``, ``charuco:9x6``) and corner detection with a
  subpixel window sized from the squares;
* :mod:`.gates` — per-view gates with reasons: sharpness / motion blur, size, stillness,
  novelty;
* :mod:`.coverage` — corner heatmap, covered image regions, distance and tilt spreads;
* :mod:`.solve` — the solve (a package, one subject per module): per-view errors, outlier
  views, the k3 rule, ``auto``'s model choice, covariance, cross-validation;
* :mod:`.uncertainty` — parameter covariance and the projection-uncertainty map;
* :mod:`.verdict` — ok / not ok, with reasons naming image regions;
* :mod:`.suggest` — where to hold the board next;
* :mod:`.session` — all of it, incrementally, with a background solve (CLI and web page);
* :mod:`.report` — the report JSON, a text summary, the uncertainty map as an image;
* :mod:`.geometry` — board placements relative to the camera;
* :mod:`.synthetic` — rendered calibration sessions with known truth.
"""

from drovisio.calibration.board import (
                                        BoardSpec,
                                        BoardSpecError,
                                        Detection,
                                        detect,
                                        parse_board,
)
from drovisio.calibration.session import (
                                        CalibrationSession,
                                        FrameCheck,
                                        FrameResult,
                                        SessionConfig,
                                        View,
)
from drovisio.calibration.solve import (
                                        CalibrationError,
                                        CalibrationResult,
                                        SolveOptions,
                                        ViewInput,
                                        solve,
)
from drovisio.calibration.suggest import Suggestion, suggest_next_pose
from drovisio.calibration.verdict import Verdict, VerdictRules, judge

__all__ = [
    "BoardSpec", "BoardSpecError", "Detection", "detect", "parse_board",
    "CalibrationSession", "FrameCheck", "FrameResult", "SessionConfig", "View",
    "CalibrationError", "CalibrationResult", "SolveOptions", "ViewInput", "solve",
    "Suggestion", "suggest_next_pose", "Verdict", "VerdictRules", "judge",
]
