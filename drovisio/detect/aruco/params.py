"""The code detector's tuning, grouped by stage (defaults measured with ``drovisio bench aruco``).

The stages, in the order :class:`~drovisio.detect.aruco.ArucoBrickDetector` runs them: OpenCV's
pass (quads and their bits), the rescue of the quads it could not read, the second look at
twice the size, the corner fit, and the brick's pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drovisio.pose import AmbiguityRule

__all__ = ["ArucoParams"]


@dataclass
class ArucoParams:
    """Tuning of the code detector (defaults measured with ``drovisio bench aruco``)."""

    # -- OpenCV's pass: quads from one adaptive threshold, their bits read by OpenCV ------
    adaptive_window: int = 5
    """Adaptive threshold window (px, odd). One window: the default three cost 3× the time
    and found fewer small codes on the drick scenes."""
    threshold_constant: float = 12.0
    """Adaptive threshold constant (grey levels below the local mean that count as black).
    OpenCV's 7 merges the black border with the darker brick faces next to it (the white
    paper rim is < 1 px at 2 m), so the quad is lost."""
    pixels_per_cell: int = 8
    """Samples per cell when the bits are read (OpenCV's 4 misreads codes of ~3 px cells)."""
    min_code_px: float = 11.0
    """Smallest code side, pixels (the code's outer border). OpenCV's perimeter limit
    measures its contour, which lies inside the code by ``initial_expand_px`` along each
    diagonal, so the rate is set from the contour of such a code for the camera's image
    size (0.06 at 640 px). The target is ≥ 15 px; fewer candidates than 8 px, same recall."""
    error_correction_rate: float = 0.6
    polygon_accuracy: float = 0.03
    """OpenCV's ``polygonalApproxAccuracyRate``: how far (× the perimeter) a candidate's
    contour may stray from its 4-gon. 0.05 read 1 code more in 1000 on the 60° lens, but
    through a fisheye it took curved, bumpy contours for codes and their poses were off by
    3 cm (``drovisio bench lens``)."""

    # -- the rescue: quads OpenCV could not read (and ring quads), read by a fit ----------
    rescue: bool = True
    """Read the quads OpenCV found but rejected, and the ring quads (see
    :func:`drovisio.detect.aruco.rescue.rescue_codes`)."""
    rescue_max: int = 60
    """At most this many quads are read again per frame."""
    rescue_max_side_px: float = 40.0
    """Rejected quads bigger than this (mean side) are not read again."""
    rescue_max_bit_errors: int = 3
    """Most misread bits a rescued code may have (fewer when our codes are closer to each
    other: :func:`drovisio.detect.aruco.families.tolerable_bit_errors`); small 36h11 codes
    have cells of 1.4–2 px, blur makes one or two of 36 read wrong. The corner fit then
    checks every cell against the code's bits (a misread code is dropped there)."""
    rescue_chance_limit: float = 1e-4
    """Highest chance that a random reading (a quad on gravel) comes within the tolerated
    bit errors of one of our codes; it bounds the tolerance (36h11: 3 errors, 2e-5 for 40
    codes; 4×4: 0)."""
    rescue_shifts_px: tuple[float, ...] = (0.0, 0.8, 1.6)
    """Outward shifts of a rescued quad's corners tried when reading it (OpenCV's contours
    lie about a pixel inside the code, a ring's hull half a pixel)."""
    rescue_min_contrast: float = 15.0
    """Grey levels a rescued code's white cells must read above its black ones."""
    rescue_max_black_offset: float = 0.35
    """A rescued code's black cells must read as its border's black within this fraction
    of the contrast (a quad on gravel has no uniform black frame)."""
    ring_quads_max: int = 30
    """For dictionaries with small cells, at most this many quads from contours OpenCV
    passed over (a code whose border touches a dark edge:
    :func:`drovisio.detect.code_reading.ring_quads`; 0: none), only in frames where OpenCV
    read one of the family's codes (the brick's other codes)."""

    # -- the second look: unread quads enlarged twice and searched again ------------------
    second_look_max: int = 6
    """Quads still unread after the rescue that get a second look at twice the size (the
    largest first; 0: none)."""
    small_cell_px: float = 2.5
    """Dictionaries whose cells are at most this wide on a 20-px code have "small cells":
    they get the ring quads and the second look. 4×4 codes (3.3 px) do not: on the bench the
    two found the last 3 of 520 bricks but made 7 false ones in 440 frames (16 bits read off
    random quads match one of our codes too often), at 2.3× the time."""
    second_look_max_side_px: float = 30.0
    """Unread quads larger than this (mean side) get no second look."""
    second_look_chance: float = 0.05
    """The budget of the second look (0.25 ms a quad): only quads whose reading shows a
    code's frame (a uniform black border and cells with contrast, at some shift) or came
    closer to one of our codes than a random pattern would with this chance (36h11 with
    30–60 ids: at most 7 bits off) get it. Bits alone are no budget: a ring's hull that
    takes in a pyramid's edge reads 9–11 bits off and still holds a code."""
    second_look_window: int = 9
    """Adaptive threshold window of the second look (px of the enlarged image)."""
    second_look_constant: float = 5.0
    """Adaptive threshold constant of the second look."""

    # -- the corner fit (:func:`drovisio.detect.corners.refine_codes`) --------------------
    initial_expand_px: float = 1.0
    """OpenCV's corners (contours of the thresholded image) lie inside the code: at the
    threshold settings above their mean signed radial error is -1.06 px (bench). The fit
    starts from them moved outward by this much along the diagonals."""
    refine_iterations: int = 2
    """Levenberg–Marquardt iterations of the corner fit (two suffice from the corrected
    start: RMS 0.17 px on the bench, against 0.23 px with three from the raw corners)."""
    refine_coarse_iterations: int = 0
    refine_lambda: float = 0.03
    max_samples: int = 200
    """Pixels per code in the corner fit (bigger codes: a random subset)."""
    band_px: float = 2.0
    """Only pixels within this distance of a modelled edge enter the corner fit."""
    outer_edge: bool = True
    """Refit each kept code with its outer edges where a uniform paper surround shows
    (:mod:`drovisio.detect.corners.outer`); off: the corners come from the interior alone."""
    corner_noise_scale: float = 1.0
    """Multiplies the corner standard deviations predicted by the photometric fit (which
    takes the noise from its own residuals). The pose solve then inflates the covariance by
    its own χ²/dof when the corners disagree more than predicted (correlated JPEG noise), so
    a further factor counts that noise twice: with 2.0 the pose errors' Mahalanobis median
    against the reported covariance was 2.0 on rendered scenes (χ²(6): 5.35), with 1.0 it is
    3.8–4.7 (``tests/pose/test_covariance_honesty.py``)."""

    # -- guided codes: a posed brick's unread codes fitted where the pose puts them -------
    guided: bool = True
    """Fit the unread codes of bricks posed from fewer codes than their layout carries, at
    their predicted place (:mod:`drovisio.detect.aruco.guided`). A second code 150 mm from
    the first turns a one-code pose's baseline of 65 mm into 215 mm."""
    guided_chance: float = 1e-3
    """Least χ²(8) chance of a guided code's corners against their prediction (under the
    pose's and the fit's covariance): a right code falls outside with this chance."""
    guided_blur_share: float = 0.5
    """Unmodelled corner error, per axis, as a share of the code's fitted blur (Gaussian σ,
    px): the fit's covariance holds pixel noise only, but a real spot (motion, a defocus
    disc, a fisheye rim's stretched spot) is not the model's separable Gaussian, and corners
    move by part of its width. Without it a one-code pose at a fisheye's rim predicted the
    other code 5σ off (1.7 px at σ 0.36 px) where it was."""
    guided_min_side_px: float = 8.0
    """Smallest predicted side (px) fitted: below, a 4×4 code's cells are under 1.4 px and
    the fit cannot read them back."""
    guided_margin_px: float = 3.0
    """Predicted corners must lie this far inside the image: the fit samples a band of
    ``band_px`` around the outer edge, plus a pixel of blur."""
    guided_coarse_iterations: int = 1
    """Corner-fit iterations with a wide blur before the usual ones: a one-code pose
    predicts the other code's corners to about a pixel, a wider basin than OpenCV's
    corrected corners need (fisheye periphery, 40 scenes: 0 accepted 11 codes, 1: 14, 2: 15
    with the same errors)."""

    guided_search_sigmas: float = 2.5
    """A prediction whose centre is uncertain beyond the fit's basin (half a cell) is fitted
    from shifted starts, half a cell apart, out to this many standard deviations along each
    axis of the centre's uncertainty (:func:`drovisio.detect.aruco.guided.start_shifts`;
    2.5: the true place lies inside the searched box with a chance of ~98 %)."""
    guided_search_max: int = 49
    """Most starts per prediction (a 7×7 grid): a bound on the time, reached only when the
    pose predicts a small code to several cells."""

    # -- the brick's pose -----------------------------------------------------------------
    max_rmse_px: float = 2.0
    """Bricks whose joint fit is worse than this (px RMS) are dropped (a wrong grouping or a
    code on a bent surface) unless the fit is explained otherwise
    (:meth:`drovisio.detect.aruco.pose.BrickSolver.fit_explained`: noisier corners, or a
    camera model that fits OpenCV's own corners no better)."""
    gravity_prior_deg: float | None = 5.0
    """With gravity, a soft prior that the brick lies flat (standard deviation, degrees;
    None: gravity only chooses between flip candidates). It covers the drone's attitude
    error and uneven ground; strong image evidence wins over it."""
    ambiguity: AmbiguityRule = field(default_factory=AmbiguityRule)
    """The planar ambiguity's rule, the same as the dot detector's
    (:mod:`drovisio.pose.ambiguity`; measured on the bench: at a χ² margin of 16, small single
    codes were flipped by corner errors, hence 25)."""
