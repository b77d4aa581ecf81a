"""``drovisio bench dots``: accuracy, robustness, speed and memory of the colour-dot detector.

Measured on the renderer's scenes (:mod:`drovisio.scenes`), with exact truth. Parts:

* ``accuracy``  random scenes (0.4–2 m, tilt ≤ 40°, gravel/grass/clutter, blur, noise, JPEG,
  lighting gain 0.8–1.2, gamma 0.9–1.1, a few red/blue props): recall, pose errors with and
  without gravity, flips, false bricks, and the bias of the reported dot centres.
* ``hidden``    the same with one or two dots of every brick unpainted, plus bricks partly
  covered by a plain brick laid across them.
* ``clutter``   scenes without any brick, photo clutter on the ground and red cups, blue
  tarpaulins and boxes: every brick reported is a false brick.
* ``lighting``  a gain × gamma grid (0.6–1.3 × 0.8–1.25) with the default palette.
* ``timing``    per-frame time against a minimal pass (cvtColor to HSV + one cv2.inRange per
  colour) on the same frames, with 1, 5 and 20 bricks in view; medians.
* ``memory``    resident memory over many frames (a loop over cached frames).
* ``kernels``   each compiled kernel against what it replaces (the numpy reference, or
  OpenCV: IPPE, undistortion, projection) on the inputs of the 20-brick timing frames.

Definitions (printed with the table):
* a brick is *eligible* when at least 4 of its dots are fully visible (inside the image,
  painted, not hidden by its own pyramids, another brick or a prop) and their median size is
  ≥ 6 px across (equivalent diameter of the projected dot, 2·√(area/π));
* *lateral error*: √(Δx² + Δy²) of ``tvec`` in the camera frame (the brick origin, centre of
  its top face); *depth error*: |Δz| / z; *yaw error*: the rotation about the brick's z axis
  of R_trueᵀ·R_est, modulo 180° for a ``rot180_z`` layout; all at ≤ 2 m from the camera;
* a *flip*: the reported orientation is more than 20° from the truth (modulo the layout's
  symmetry); *unflagged* when the pose is not marked ``ambiguous``;
* a *false brick*: a reported brick with no true brick of that layout within 8 cm.

Rendered frames are cached (PNG + truth JSON) in ``--cache`` (default
``~/.cache/drovisio/bench-dots``), so a second run only measures.
"""

from __future__ import annotations

from drovisio.bench.dots.frames import FrameSource
from drovisio.bench.dots.run import main

__all__ = ["FrameSource", "main"]
