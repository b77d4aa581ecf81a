"""Bricks from their ArUco codes: detection, unbiased corners, joint pose, resolved flips.

The stages of :class:`ArucoBrickDetector` for one frame, one module each (the detector in
:mod:`.detector` runs them in order and times each in :attr:`ArucoBrickDetector.timing`; the
tuning, :class:`ArucoParams`, groups their parameters by stage in :mod:`.params`):

1. **OpenCV's pass** (:mod:`.opencv_pass`). OpenCV's ``ArucoDetector`` with parameters tuned
   for small codes (≥ 14 px) on cluttered ground and for speed (one small adaptive-threshold
   window instead of three, a stricter threshold constant that keeps thin white paper rims
   apart from dark brick faces, 8 samples per cell when reading the bits, no candidate
   smaller than 11 px), and a dictionary made of *exactly* the ids the loaded layouts own
   (fewer false decodes; :mod:`.families`).
2. **The rescue** (:mod:`.rescue`). Quads OpenCV found but could not read, and for
   dictionaries with small cells (6×6, 36h11) the quads of thresholded contours it passed
   over (a code whose border merges with a pyramid's shaded side), are read again by a
   least-squares fit of their blurred cells (:class:`drovisio.detect.code_reading.CodeReader`),
   with as many misread bits as the codes' distances allow (36h11: 3, 4×4: 0).
3. **The second look** (:mod:`.second_look`). Quads still unread whose reading shows a code's
   frame and contrast, or comes closer to one of our codes than chance, are searched again at
   twice the size. On 815 rendered tag36h11 bricks (``drovisio bench aruco --dictionary
   DICT_APRILTAG_36h11 --apriltag --bricks 4 --frames 300 --seed 5000 --empty 0``): codes of
   14–20 px 76.3 % (OpenCV's pass alone) → 96.2 % (AprilTag 3: 74.0 %), all ≥ 14 px
   94.7 % → 99.3 % (93.6 %), no false brick, at 0.86× the time of plain ``detectMarkers``.
4. **The corner fit** (:mod:`.corner_fit`). Every decoded code is refined by
   :func:`drovisio.detect.corners.refine_codes` (photometric fit of the code's interior,
   unbiased by the outer edge's surroundings), all codes of the frame in one batch, starting
   from OpenCV's corners moved outward by their measured bias. A code the model does not fit,
   or whose cells do not read back as its bits (a decoy, a partly hidden code), is dropped.
5. **Grouping** (:mod:`.grouping`). Codes are grouped by their layout's id blocks into brick
   instances; an id read more than once is posed apart, copy by copy.
6. **The pose** (:mod:`.pose`). One joint PnP over every visible code of a brick
   (:func:`drovisio.pose.solve_brick_pose`), with the corners' covariance from the fit; a code
   with a corner far beyond the noise the brick's own residuals show is left out of the final
   refinement (its corners share one wrong fit). Flip candidates are chosen with gravity when
   known, then with the "up" of other, decided bricks in the same frame (bricks on one ground
   are parallel), then with the previous pose of the same brick when a
   :class:`drovisio.pose.PoseHistory` is given (a stream), then with the reprojection.
   Undecided poses are flagged ``ambiguous`` with the alternative.
7. **The output** (:mod:`.output`): one :class:`~drovisio.detect.result.BrickPose` per brick.

Typical use::

    det = ArucoBrickDetector(camera, layouts)
    poses = det.detect(image_bgr, gravity=g)      # list[BrickPose]
"""

from drovisio.detect.aruco.codes import CodeDetection
from drovisio.detect.aruco.detector import ArucoBrickDetector, ArucoTiming, detect_aruco
from drovisio.detect.aruco.families import plain_detector
from drovisio.detect.aruco.params import ArucoParams

__all__ = [
    "ArucoBrickDetector",
    "ArucoParams",
    "ArucoTiming",
    "CodeDetection",
    "detect_aruco",
    "plain_detector",
]
