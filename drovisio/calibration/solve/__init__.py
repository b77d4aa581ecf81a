"""The calibration solve: intrinsics, per-view errors, outlier views, fixed coefficients,
covariance, projection-uncertainty map and cross-validation.

One subject per module: :mod:`.results` (options, views, the result), :mod:`.models` (the
lens models' names), :mod:`.starts` (where each solve starts), :mod:`.checks` (converged and
determined, or refused), :mod:`.fit` (one model on fixed views), :mod:`.rules` (the k3 rule,
outlier corners), :mod:`.choice` (``auto``), :mod:`.cross_validation` and :mod:`.calibrate`
(the whole solve).

Rules (stated once here, reported in the result):

* **RMS** (``rms_px``): √(mean over all kept corners of |projected − detected|²), pixels —
  OpenCV's ``calibrateCamera`` return value. Per view the same over that view's corners.
* **Outlier views**: after a solve, the view with the largest per-view RMS is rejected when it
  exceeds both 2.5 × the median per-view RMS and the median + 0.15 px; the solve is repeated
  until no view qualifies (never below 4 views). Such a view disagrees with the others (blur,
  a bent or moving board, a wrong detection).
* **The solver** (:mod:`drovisio.calibration.lm`): Levenberg–Marquardt over the intrinsics
  and every board pose, each step accepted only when it lowers the RMS (which therefore
  never grows), serial (the same views give the same numbers, bit for bit, with one thread
  or many). Every model starts from the solve of the same corners by a simpler one: OpenCV's
  closed-form pinhole start (``initCameraMatrix2D``) → pinhole → plumb_bob (k1 k2 p1 p2,
  then k3) → rational / thin prism / tilted from plumb_bob's coefficients; the fisheye from
  plumb_bob's K, else the pinhole's K, else its own closed form (f = diagonal / π, centred),
  k1 k2 first, then all four.
* **Converged and determined, or refused** (:func:`.checks.diagnose`): a solve is not written when
  its lens mapping folds back (stops growing with the angle from the axis) inside the field
  the board covered, when its RMS exceeds both 10 × the corners' own noise
  (:func:`corner_noise_px`, measured without a lens model) and that noise + 2 px, or when
  the 1-σ of fx, fy, cx or cy exceeds 10 % of the focal length, or when its projection
  uncertainty (1-σ, see below) at the image's median point exceeds 1 % of the focal length
  (each intrinsic can be known while the model is not). It is then solved again from
  the next start, then with its highest-order coefficients held at 0 (fisheye k3 k4,
  rational k4–k6, plumb_bob k3; said in ``fixed``), and otherwise refused in one line that
  names the model, the cause and the fix.
* **Fixed coefficients**: k3 (the r⁶ term) of plumb_bob is fixed to 0 when the data do not
  show that it differs from 0, i.e. when |k3| < 2·σ(k3) in the free solve (a two-sided 95 %
  test; it is a likelihood-ratio test for one parameter). The fixed model is what is written;
  the free solve's k3 ± σ and its uncertainty are kept in the result (``free_model``), so the
  choice can be checked. The same rule holds the other models' highest-order coefficients
  (fisheye k3 k4, rational k4–k6...) at 0 when any of them is within 2σ of 0.
* **Outlier corners**: before the outlier views, a corner farther from its projection than
  5 × the median corner residual (and 0.5 px) is dropped, at most 5 % of a view's corners, and
  listed with its residual (``rejected_corners``).
* **Lens model** (``model``): plumb_bob (5 coefficients), rational (8), thin_prism (12),
  tilted (14) or fisheye (Kannala–Brandt, 4). ``auto`` chooses among plumb_bob, fisheye and
  rational (the thin prism and the tilted sensor are asked for by name), see
  :func:`choose_model`: a model that does not converge on all views, or that they do not
  determine, is refused; each model is solved without every sixth view (6 folds) and scored
  per held-out view posed through it; a view a model cannot pose is its failure on that view
  only, and a fold a model cannot solve is no evidence either way. From fewer coefficients to
  more, a model replaces the one chosen when it poses more views and is not worse (10 %) on
  those both posed, or is 10 % better there beyond twice the per-view standard error
  (``model_choice`` says the figures and why). It is chosen before the outlier rules, which
  need the right model.
* **Covariance / uncertainty map**: see :mod:`drovisio.calibration.uncertainty`.
* **Cross-validation**: the kept views are split into two disjoint halves (alternating views),
  each is solved with the same model, and the two models are compared over the image:
  |π_B(ray_A(q)) − q| on the uncertainty grid, pixels (p50, p95, max), with the camera frame
  fixed (comparable with the uncertainty map) and after the rotation that best aligns the two
  frames (a principal-point difference is mostly such a rotation). It needs 8 views.
"""

from drovisio.calibration.solve.calibrate import solve
from drovisio.calibration.solve.checks import corner_noise_px, fold_angle
from drovisio.calibration.solve.choice import AUTO_MODELS, HELD_OUT_FOLDS, choose_model
from drovisio.calibration.solve.fit import fit_model
from drovisio.calibration.solve.models import MODEL_CHOICES, MODELS, unknown_model
from drovisio.calibration.solve.results import (
    RMS_DEFINITION,
    CalibrationError,
    CalibrationResult,
    Model,
    SolveOptions,
    ViewFit,
    ViewInput,
)
from drovisio.calibration.solve.starts import clear_cache

__all__ = ["CalibrationError", "SolveOptions", "ViewInput", "ViewFit", "CalibrationResult",
           "Model", "solve", "fit_model", "choose_model", "corner_noise_px", "fold_angle",
           "MODELS", "MODEL_CHOICES", "AUTO_MODELS", "HELD_OUT_FOLDS", "RMS_DEFINITION",
           "unknown_model", "clear_cache"]
