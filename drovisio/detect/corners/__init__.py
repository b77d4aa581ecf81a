"""Unbiased sub-pixel corners of square fiducial codes by fitting a photometric model.

Why not OpenCV's corner refinement: the outer edge of a printed code sits between its black
border and whatever is around it (a thin strip of paper, then the brick); once blurred, that
neighbourhood pulls every local edge or corner estimator (gradient peak, threshold crossing,
``cornerSubPix``) by 0.3–0.7 px, a bias measured on renders. So each code is first fitted *as
a whole* from the inside: knowing the code's bits (from its decoded id), the model predicts
every pixel of the code's interior,

    I(p) = B + (W − B) · S(u, v),        (u, v) = G(x(p))

where ``x(p)`` is the undistorted, normalised image coordinate of pixel ``p`` (exact, from
the camera model), ``G`` the 8-parameter homography from the image plane to the code plane in
cell units (the outer border spans [0, n]², n = bits + 2), and ``S`` the code's white cells
blurred by a Gaussian (``s_u``, ``s_v`` in cells and their correlation ``rho``: defocus,
motion, pixel area, seen through the code's own obliquity, :mod:`.model`). The thirteen
parameters (G, B, W, s_u, s_v, rho) are fitted by Levenberg–Marquardt to the pixels of the
region [1 − a, n − 1 + a]² (the inner edges of the border and every bit edge) that lie within
a couple of pixels of a modelled edge (a random subset for big codes: a regular one aliases
with the edges), batched over all codes of a frame. Blur acts symmetrically on every modelled
edge, so the fitted homography, and the outer corners ``G⁻¹((0,0), (n,0), (n,n), (0,n))``,
carry no blur bias; working in undistorted coordinates makes lens distortion exact as well.

The fit also yields, per code, the corners' 8×8 covariance (from the Jacobian and the fit's
residuals, widened where neighbouring pixels share their errors: :mod:`.covariance`), the
contrast, the blur, and two checks used to reject decoys and partly
hidden codes: the goodness of fit, and a deblurred read-back of every inner cell at the fitted
geometry and blur (its correlation included), judged by the code's own two brightness classes
(:func:`cell_verdicts`: real JPEGs read cells at 0.7 / 0.3 that still lie 15+ spreads apart);
a corner that moved farther from its start than the frame's measured start noise allows is
refused too (:func:`.fit._move_limits`).

Where the code *is* surrounded by uniform paper (a printed sheet, a ChArUco square, an
AprilTag's white ring), its outer edges are the best-placed evidence there is, and the
interior fit's extrapolation to them carries the model's error (a camera's tone curve after
the optics' blur moves every edge toward the dark side: the interior sees its white cells
grown and places the outer corners outward, 0.4 px on OpenCV's ChArUco photo). So every kept
code is refitted with its surround as one more level (:mod:`.outer`), and the refit is kept
only where the data say the surround is uniform paper: each side's residuals beyond the edge
no larger than inside it, and the surround as bright as the white cells. A thin margin on a
darker brick (every rendered drick) fails those tests and keeps the interior fit. The refit's
covariance holds the two fits' disagreement too: the pixel noise alone said 0.055 px where
the corners lie 0.23 px from AprilTag 3's on OpenCV's ChArUco photo (one lone code's pose then
came out as its mirror, unflagged); half the distance between the corners with and without
the outer edges, added on every coordinate, gives 0.27 px there and keeps a drawn code's
corners within their covariance under a tone curve (chi-square 3.9, 40 without).

Where a code's cells are no flat square of its border (the interior fit, extrapolated, moved
a corner farther than the frame's start noise allows: the rim of a photo undistorted with a
lens model that does not fit it, a bent print), the code is kept where its four outer edge
lines meet (:mod:`.edges`) if every other check passed, each side is an edge inside the image
(not the image's border, not noise), those corners lie within 2.5 cells of the interior
fit's, and the cells read right there too; its covariance holds the distance to the interior
fit's corners. On pupil-labs' tag photos one code of 56 is (0.24 px RMS from AprilTag 3's
corners, flagged ambiguous); on rendered drick scenes none; decoys in rendered clutter whose
interior fit moved far read wrong cells at the fit, and their edges are not tried.

Measured on rendered drick scenes (``drovisio bench aruco``, blur σ ≤ 1 px, 2852 corners):
mean signed radial error +0.004 px, RMS 0.20 px; OpenCV's corners at the detector's settings
−1.04 px and 1.21 px.

The package, one subject per module: :mod:`.fit` (:func:`refine_codes`, its stages in order),
:mod:`.model` (the photometric model and its Jacobian), :mod:`.samples` (which pixels enter
the fit; compiled in :mod:`.samples_kernels`, numba, where numba is installed, the same
samples as the numpy reference; the fit stays numpy: its dense float32 arithmetic is faster
vectorised), :mod:`.covariance` (the parameters' covariance from the residuals; its kernel
compiled in :mod:`.covariance_kernels`), :mod:`.cells` (the read-back of the cells),
:mod:`.outer` (the refit with the outer edges), :mod:`.edges` (the outer edge lines).

Conventions: pixel (0, 0) is the centre of the top-left pixel; corners in OpenCV order TL, TR,
BR, BL of the printed code (the order of ``cv2.aruco`` and of the layout file).
"""

from drovisio.detect.corners.cells import cell_verdict, cell_verdicts
from drovisio.detect.corners.fit import MAX_SAMPLES, RefinedCode, refine_codes
from drovisio.detect.corners.samples import normalized_grid

__all__ = [
    "MAX_SAMPLES",
    "RefinedCode",
    "cell_verdict",
    "cell_verdicts",
    "normalized_grid",
    "refine_codes",
]
