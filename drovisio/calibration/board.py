"""Calibration targets: the board specification and corner detection with subpixel refinement.

Board specs (the ``--board`` argument of ``drovisio calibrate``):

* ``chessboard:COLSxROWS`` — a plain chessboard; COLS × ROWS count the *inner* corners
  (a board of 10 × 7 squares is ``chessboard:9x6``), as OpenCV's ``findChessboardCorners``.
* ``charuco:COLSxROWS[:DICTIONARY[:MARKER_RATIO]]`` — a ChArUco board, again counted in inner
  corners (so it has (COLS+1) × (ROWS+1) squares), ArUco dictionary (default ``DICT_4X4_50``)
  and marker side as a fraction of the square (default 0.75). ChArUco tolerates a partly
  visible or partly occluded board: each corner carries its id.

Object points follow OpenCV's calibration convention: inner corner (i, j) (i along the
columns, j along the rows) is at (i·square, j·square, 0) metres, row-major, i.e. the order
``findChessboardCorners`` returns.

Subpixel refinement: ``cv2.cornerSubPix`` with a half-window sized from the board's smallest
square side seen in the image, ``half = clip(round(0.3 × side_px), 2, 10)``. A fixed window is
wrong both ways: too small on a near board (few gradient pixels, noisy) and too large on a far
or tilted one, where it reaches over the neighbouring corners and biases the corner. Measured on
OpenCV's 13 sample views: the tutorial's ``winSize=(11, 11)`` (a 23 × 23 px window) makes view
left02 (squares of 22 px) an outlier at 1.22 px RMS against a median of 0.19 px, while the sized
window gives 0.16 px there (all views within 1.4 × the median).

Finding a chessboard: a live frame is searched once, with OpenCV's quick check that gives up
early where no board is (most live frames). A still image (a file, an upload, a manual
capture) is one the user says holds the board, so where that search fails it is searched
again without the quick check, then by OpenCV's other finder (``findChessboardCornersSB``,
exhaustive): on a real 1920 × 1208 fisheye set (ROS's ``camera_calibration_fisheye``
reference, 63 views) the quick check alone found 55 boards, the full search 59, with the
other finder 62 (OpenCV's default search: 59).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.errors import InputError

__all__ = [
    "BoardSpec", "BoardSpecError", "Detection", "parse_board", "detect", "refine_window",
    "to_gray", "min_square_px",
]

#: Half-window of ``cornerSubPix`` as a fraction of the smallest square side in pixels.
WINDOW_FRACTION = 0.3
WINDOW_MIN, WINDOW_MAX = 2, 10
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
_CB_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
_SB_FLAGS = cv2.CALIB_CB_EXHAUSTIVE
_KINDS = ("chessboard", "charuco")


class BoardSpecError(InputError):
    """A board spec or square size that cannot be used; the message says what is expected."""


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target.

    Args:
        kind: ``"chessboard"`` or ``"charuco"``.
        cols: Inner corners along a row (the board's x axis).
        rows: Inner corners along a column (y axis).
        square: Side of one square, metres.
        dictionary: ArUco dictionary name (ChArUco only).
        marker_ratio: Marker side / square side (ChArUco only).
    """

    kind: str
    cols: int
    rows: int
    square: float
    dictionary: str = "DICT_4X4_50"
    marker_ratio: float = 0.75
    _charuco: object = field(default=None, compare=False, repr=False)

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows) as OpenCV's chessboard functions want it."""
        return (self.cols, self.rows)

    @property
    def width_m(self) -> float:
        """Outer size of the squared area along x, metres ((cols + 1) squares)."""
        return (self.cols + 1) * self.square

    @property
    def height_m(self) -> float:
        return (self.rows + 1) * self.square

    def spec(self) -> str:
        """The spec string this board parses from (``chessboard:9x6``)."""
        s = f"{self.kind}:{self.cols}x{self.rows}"
        if self.kind == "charuco":
            s += f":{self.dictionary}:{self.marker_ratio:g}"
        return s

    def object_points(self) -> np.ndarray:
        """(cols·rows, 3) inner corners in the board frame, metres, row-major (float64)."""
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        return np.stack([i.ravel() * self.square, j.ravel() * self.square,
                         np.zeros(i.size)], axis=1).astype(np.float64)

    def outline(self) -> np.ndarray:
        """(4, 3) outer corners of the squared area in the board frame (for drawing hints)."""
        s = self.square
        x0, y0, x1, y1 = -s, -s, self.cols * s, self.rows * s
        return np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)

    def charuco_board(self):
        """The ``cv2.aruco.CharucoBoard`` (ChArUco only; built once)."""
        if self.kind != "charuco":
            raise ValueError("not a ChArUco board")
        if self._charuco is None:
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
            b = cv2.aruco.CharucoBoard((self.cols + 1, self.rows + 1), self.square,
                                       self.square * self.marker_ratio, d)
            object.__setattr__(self, "_charuco", b)
        return self._charuco

    def to_json(self) -> dict:
        return {"spec": self.spec(), "kind": self.kind, "cols": self.cols, "rows": self.rows,
                "square_m": self.square}


def _dictionary_name(text: str) -> str:
    """OpenCV's spelling of a dictionary name typed in any case (``dict_apriltag_16h5`` →
    ``DICT_APRILTAG_16h5``: AprilTag names are mixed-case)."""
    want = text.strip().upper()
    for name in dir(cv2.aruco):
        if name.upper() == want and name.startswith("DICT_"):
            return name
    return text.strip()


def dictionary_size(name: str) -> int:
    """How many codes OpenCV's predefined dictionary ``name`` holds, read from the dictionary
    object itself (``DICT_APRILTAG_16h5`` has 30, a name says nothing reliable).

    Raises:
        BoardSpecError: not one of OpenCV's predefined dictionaries.
    """
    value = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    try:
        d = cv2.aruco.getPredefinedDictionary(value) if isinstance(value, int) else None
    except cv2.error:
        d = None
    if d is None:
        raise BoardSpecError(f"unknown ArUco dictionary {name!r} (e.g. DICT_4X4_50, "
                             "DICT_5X5_100, DICT_APRILTAG_36h11)")
    return int(d.bytesList.shape[0])


def parse_board(spec: str, square: float) -> BoardSpec:
    """Parse ``chessboard:9x6`` (or ``charuco:9x6[:DICT[:RATIO]]``) and a square size in metres.

    Raises:
        BoardSpecError: with a message naming what is wrong and the expected form.
    """
    form = ("expected KIND:COLSxROWS counting inner corners, e.g. chessboard:9x6 "
            "(a board of 10x7 squares) or charuco:9x6")
    if not isinstance(spec, str) or not spec.strip():
        raise BoardSpecError(f"board spec is empty; {form}")
    parts = spec.strip().split(":")
    kind = parts[0].lower()
    if kind not in _KINDS:
        raise BoardSpecError(f"board spec {spec!r}: unknown kind {parts[0]!r}; {form}")
    if len(parts) < 2:
        raise BoardSpecError(f"board spec {spec!r}: missing the size; {form}")
    cols, rows = _parse_size(spec, parts[1], form)
    sq = _parse_square(square)
    if kind == "chessboard":
        if len(parts) > 2:
            raise BoardSpecError(f"board spec {spec!r}: a chessboard takes no options; {form}")
        return BoardSpec("chessboard", cols, rows, sq)
    return _parse_charuco(spec, parts, cols, rows, sq)


def _parse_size(spec: str, size: str, form: str) -> tuple[int, int]:
    """(cols, rows) of inner corners of a spec's ``COLSxROWS`` field."""
    m = re.fullmatch(r"\s*(\d{1,6})\s*[xX×]\s*(\d{1,6})\s*", size)
    if not m:
        raise BoardSpecError(f"board spec {spec!r}: size {size!r} is not COLSxROWS; {form}")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 3 or rows < 3:
        raise BoardSpecError(f"board spec {spec!r}: needs at least 3x3 inner corners "
                             f"(got {cols}x{rows}); {form}")
    if cols > 200 or rows > 200:
        raise BoardSpecError(f"board spec {spec!r}: {cols}x{rows} inner corners is not a "
                             "plausible board")
    return cols, rows


def _parse_square(square: float) -> float:
    """The square size, metres, checked to be a plausible length given in metres."""
    try:
        sq = float(square)
    except (TypeError, ValueError):
        raise BoardSpecError(f"square size {square!r} is not a number (metres, e.g. 0.025)"
                             ) from None
    if not np.isfinite(sq) or sq <= 0:
        raise BoardSpecError(f"square size {square!r} must be a positive length in metres, "
                             "e.g. 0.025")
    if sq < 0.001:
        raise BoardSpecError(f"square size {sq:g} m is smaller than a millimetre: give it in "
                             "metres, e.g. 0.025 for 25 mm")
    if sq > 1.0:
        raise BoardSpecError(f"square size {sq:g} m is implausible: give it in metres "
                             f"(did you mean {sq / 1000:g} m, i.e. {sq:g} mm?)")
    return sq


def _parse_charuco(spec: str, parts: list[str], cols: int, rows: int, sq: float
                   ) -> BoardSpec:
    """A ChArUco board's ``[:DICTIONARY[:MARKER_RATIO]]`` fields, checked against the
    dictionary's size."""
    dictionary = _dictionary_name(parts[2]) if len(parts) > 2 and parts[2] else "DICT_4X4_50"
    try:
        dictionary_size(dictionary)
    except BoardSpecError as e:
        raise BoardSpecError(f"board spec {spec!r}: {e}") from None
    ratio = 0.75
    if len(parts) > 3:
        try:
            ratio = float(parts[3])
        except ValueError:
            raise BoardSpecError(f"board spec {spec!r}: marker ratio {parts[3]!r} is not a "
                                 "number in (0, 1)") from None
        if not 0.2 <= ratio < 1.0:
            raise BoardSpecError(f"board spec {spec!r}: marker ratio {ratio:g} must be in "
                                 "[0.2, 1) (marker side / square side)")
    if len(parts) > 4:
        raise BoardSpecError(f"board spec {spec!r}: too many fields; "
                             "charuco:COLSxROWS[:DICTIONARY[:MARKER_RATIO]]")
    n_markers = ((cols + 1) * (rows + 1)) // 2
    dict_size = dictionary_size(dictionary)  # from OpenCV's object: AprilTag names have no _N
    if n_markers > dict_size:
        raise BoardSpecError(f"board spec {spec!r}: the board needs {n_markers} markers but "
                             f"{dictionary} has {dict_size}")
    return BoardSpec("charuco", cols, rows, sq, dictionary, ratio)


@dataclass
class Detection:
    """Corners of one board found in one image.

    Attributes:
        corners: (N, 2) refined corner pixels (float64).
        ids: (N,) indices into ``BoardSpec.object_points()`` (all of them for a chessboard).
        image_size: (width, height) of the image.
        square_px: Smallest square side seen, pixels.
        window: Half-window used by ``cornerSubPix``.
    """

    corners: np.ndarray
    ids: np.ndarray
    image_size: tuple[int, int]
    square_px: float
    window: int

    def object_points(self, board: BoardSpec) -> np.ndarray:
        return board.object_points()[self.ids]

    @property
    def n(self) -> int:
        return int(len(self.ids))

    def to_json(self) -> dict:
        return {"corners": np.round(self.corners, 5).tolist(), "ids": self.ids.tolist(),
                "image_size": list(self.image_size), "square_px": round(self.square_px, 3),
                "window": self.window}

    @classmethod
    def from_json(cls, d: dict) -> Detection:
        return cls(corners=np.asarray(d["corners"], float).reshape(-1, 2),
                   ids=np.asarray(d["ids"], int), image_size=tuple(d["image_size"]),
                   square_px=float(d["square_px"]), window=int(d["window"]))


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit single-channel view of a BGR/BGRA/gray 8- or 16-bit image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def min_square_px(corners: np.ndarray, ids: np.ndarray, board: BoardSpec) -> float:
    """Smallest distance between two detected corners that are neighbours on the board."""
    pos = {int(k): c for k, c in zip(ids, corners)}
    best = np.inf
    for k, c in pos.items():
        i, j = k % board.cols, k // board.cols
        for nb in ((k + 1) if i + 1 < board.cols else None, (k + board.cols)
                   if j + 1 < board.rows else None):
            if nb is not None and nb in pos:
                best = min(best, float(np.hypot(*(pos[nb] - c))))
    return best


def refine_window(square_px: float) -> int:
    """Half-window of ``cornerSubPix`` for a board whose smallest square is ``square_px``."""
    if not np.isfinite(square_px):
        return WINDOW_MIN
    return int(np.clip(round(WINDOW_FRACTION * square_px), WINDOW_MIN, WINDOW_MAX))


def _find_chessboard(gray: np.ndarray, size: tuple[int, int], still: bool
                     ) -> np.ndarray | None:
    """(N, 2) float32 inner corners in OpenCV's order, or None (see the module: a still
    image is searched further than a live frame)."""
    found, c = cv2.findChessboardCorners(gray, size, None, _CB_FLAGS)
    if not found and still:
        found, c = cv2.findChessboardCorners(gray, size, None,
                                             _CB_FLAGS & ~cv2.CALIB_CB_FAST_CHECK)
        if not found:
            found, c = cv2.findChessboardCornersSB(gray, size, flags=_SB_FLAGS)
    if not found or c is None or len(c) != size[0] * size[1]:
        return None
    return np.asarray(c, np.float32).reshape(-1, 2)


def detect(image: np.ndarray, board: BoardSpec, window: int | None = None,
           still: bool = False) -> Detection | None:
    """Find the board's inner corners with subpixel accuracy.

    Args:
        image: BGR or gray image (8 or 16 bit).
        board: The target.
        window: Force this ``cornerSubPix`` half-window (default: sized from the squares).
        still: A still image said to hold the board (a file, an upload, a capture):
            searched further where the quick search finds none; a live frame is not.

    Returns:
        The detection, or None when the board is not found (or fewer than 6 ChArUco corners).
    """
    gray = to_gray(image)
    h, w = gray.shape
    if board.kind == "chessboard":
        corners = _find_chessboard(gray, board.pattern_size, still)
        if corners is None:
            return None
        ids = np.arange(board.n_corners)
    else:
        det = cv2.aruco.CharucoDetector(board.charuco_board())
        cc, cids, _, _ = det.detectBoard(gray)
        if cids is None or len(cids) < 6:
            return None
        corners = np.asarray(cc, np.float32).reshape(-1, 2)
        ids = np.asarray(cids, int).ravel()
        order = np.argsort(ids)
        corners, ids = corners[order], ids[order]
    side = min_square_px(corners, ids, board)
    if not np.isfinite(side):
        return None
    if window is not None:
        win = int(window)
    elif board.kind == "charuco":
        # the window must stay in the white margin between the corner and the markers of the
        # two white squares: their edges pull the corner (measured on renders: RMS 0.20 px
        # with the chessboard's window, 0.07 px inside the margin)
        margin = (1.0 - board.marker_ratio) / 2.0 * side
        win = int(np.clip(min(refine_window(side), round(margin)), WINDOW_MIN, WINDOW_MAX))
    else:
        win = refine_window(side)
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2).copy(), (win, win), (-1, -1),
                               _SUBPIX_CRITERIA)
    refined = np.asarray(refined, np.float64).reshape(-1, 2)
    # a corner that wandered off (cornerSubPix diverging on a smeared image) is dropped
    moved = np.hypot(*(refined - corners).T)
    keep = moved <= max(2.0, 0.5 * side)
    return Detection(corners=refined[keep], ids=ids[keep], image_size=(w, h),
                     square_px=float(side), window=win)
