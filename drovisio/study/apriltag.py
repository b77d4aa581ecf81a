"""AprilTag 3 as a peer (``pupil-apriltags``, the ``peers`` extra): its own families, and
any of OpenCV's ArUco dictionaries read by AprilTag 3's own detector.

AprilTag 3's quad detector (adaptive threshold, segmentation, line fits to the border) and
its decoder work on any square code with a one-cell black border; a family is only the table
of its codes and where each bit lies. OpenCV's ArUco dictionaries (4×4 to 7×7, the original
ArUco, MIP 36h12) are codes of that kind, so they are handed to AprilTag 3 as families built
from OpenCV's own tables: each code's inner cells laid out as AprilTag lays out its own
families' bits (four groups, each the previous one turned by 90° — what its decoder's
rotation of a code word assumes — and an odd size's centre cell last), white = 1, the code
seen turned by 180° (so that an AprilTag dictionary built this way is bit for bit AprilTag's
own table: checked in the tests). This gives a reading of codes of any dictionary that shares
nothing with Drovisio's or OpenCV's: the reference for code corners on ArUco and ChArUco
photos in ``drovisio bench real``.

Bit errors are corrected as each dictionary's own detector corrects them: AprilTag's families
up to 2 bits (AprilTag 3's own setting), an ArUco dictionary as OpenCV's ``ArucoDetector``
does at its defaults (its ``maxCorrectionBits`` × ``errorCorrectionRate``, at most 2), so
that a dictionary with close codes (4×4) is not read into false codes more often than its
own detector would.

Corners: :class:`AprilTagReader` gives them in OpenCV's order (TL, TR, BR, BL of the printed
code) and pixel convention (pixel centres at integers: AprilTag's corners − 0.5 px).

pupil-apriltags' ``Detector.__del__`` frees the families before the detector that reads
them; every detector here lives until the process ends (:func:`_forget_apriltag_detectors`).
"""

from __future__ import annotations

import atexit
import ctypes
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drovisio.layout import aruco_dictionary_id

__all__ = ["APRILTAG_FAMILIES", "APRILTAG_PIXEL_OFFSET", "AprilTagCode", "AprilTagReader",
           "apriltag_detector", "apriltag_reader", "aruco_family_bits"]

#: AprilTag 3's own family of each OpenCV AprilTag dictionary that pupil-apriltags ships
APRILTAG_FAMILIES = {"DICT_APRILTAG_36h11": "tag36h11", "DICT_APRILTAG_25h9": "tag25h9",
                     "DICT_APRILTAG_16h5": "tag16h5"}

#: AprilTag 3's corners minus OpenCV's for the same pixels (measured on renders in the tests)
APRILTAG_PIXEL_OFFSET = 0.5

#: AprilTag's corner order → OpenCV's (AprilTag winds the other way: measured on renders)
_TO_OPENCV_ORDER = [1, 0, 3, 2]

_APRILTAG_DETECTORS: dict[tuple[str, bool], Any] = {}


def apriltag_detector(families: str, defaults: bool = False) -> Any:
    """pupil-apriltags' detector for AprilTag families (``"tag36h11"``), one per family and
    settings for the process: decimate 1 and one thread (the study's settings), or
    pupil-apriltags' own defaults (``defaults=True``, as a user would run it).

    Raises:
        ImportError: pupil-apriltags is not installed.
    """
    from pupil_apriltags import Detector  # deferred: an optional dependency

    key = (families, defaults)
    det = _APRILTAG_DETECTORS.get(key)
    if det is None:
        det = Detector(families=families) if defaults else Detector(
            families=families, nthreads=1, quad_decimate=1.0, quad_sigma=0.0, refine_edges=1,
            decode_sharpening=0.25)
        _APRILTAG_DETECTORS[key] = det
    return det


@atexit.register
def _forget_apriltag_detectors() -> None:
    """pupil-apriltags' ``Detector.__del__`` destroys the tag families before the detector
    that still reads them (a use-after-free): freed at interpreter exit, a detector corrupts
    the heap and the process aborts ("malloc(): mismatching next->prev_size") after its work
    is done. The process is ending: leave their memory to the system instead."""
    for det in _APRILTAG_DETECTORS.values():
        det.tag_detector_ptr = None
    _APRILTAG_DETECTORS.clear()


# ------------------------------------------------------------------ ArUco dictionaries
def _bit_positions(n: int) -> list[tuple[int, int]]:
    """Where AprilTag reads each bit of an n×n code, (x, y) in cells from the black
    border's outer corner (the data cells are 1..n): the first quarter row by row (one cell
    of each orbit under a quarter turn), then that quarter turned by 90° three times
    ((x, y) → (n + 1 − y, x)), an odd size's centre last. For n = 6 this is tag36h11's own
    layout."""
    def turn(c: tuple[int, int]) -> tuple[int, int]:
        return n + 1 - c[1], c[0]

    first: list[tuple[int, int]] = []
    taken: set[tuple[int, int]] = set()
    centre = ((n + 1) // 2, (n + 1) // 2) if n % 2 else None
    for y in range(1, n + 1):
        for x in range(1, n + 1):
            c = (x, y)
            if c in taken or c == centre:
                continue
            first.append(c)
            for _ in range(4):
                taken.add(c)
                c = turn(c)
    groups = [first]
    for _ in range(3):
        groups.append([turn(c) for c in groups[-1]])
    out = [c for g in groups for c in g]
    return out + ([centre] if centre else [])


def aruco_family_bits(dictionary: str) -> tuple[np.ndarray, list[tuple[int, int]], int, int]:
    """An OpenCV dictionary as an AprilTag family's table.

    Returns:
        (codes (N,) uint64 words, the bits' (x, y) cells in word order from the most
        significant bit, the code's size n in cells without border, the error bits the
        dictionary corrects).
    """
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    n = int(d.markerSize)
    pos = _bit_positions(n)
    codes = np.zeros(len(d.bytesList), np.uint64)
    for k in range(len(d.bytesList)):
        img = cv2.aruco.generateImageMarker(d, k, n + 2, borderBits=1) > 127
        seen = img[::-1, ::-1]  # turned by 180°: AprilTag's own tables read so
        w = 0
        for x, y in pos:
            w = (w << 1) | int(seen[y, x])
        codes[k] = w
    if dictionary in APRILTAG_FAMILIES:
        return codes, pos, n, 2  # as AprilTag 3 reads its own families
    # as OpenCV's detector corrects this dictionary at its defaults (maxCorrectionBits times
    # errorCorrectionRate 0.6, truncated): a 4x4 code, whose 16 bits leave little room
    # between codes, is read with no error corrected
    rate = cv2.aruco.DetectorParameters().errorCorrectionRate
    return codes, pos, n, min(2, int(d.maxCorrectionBits * rate))


class _Family(ctypes.Structure):
    """apriltag_family_t as AprilTag 3 declares it (``impl``: its decode table)."""

    _fields_ = [("ncodes", ctypes.c_uint32), ("codes", ctypes.POINTER(ctypes.c_uint64)),
                ("width_at_border", ctypes.c_int), ("total_width", ctypes.c_int),
                ("reversed_border", ctypes.c_bool), ("nbits", ctypes.c_uint32),
                ("bit_x", ctypes.POINTER(ctypes.c_uint32)),
                ("bit_y", ctypes.POINTER(ctypes.c_uint32)),
                ("h", ctypes.c_uint32), ("name", ctypes.c_char_p), ("impl", ctypes.c_void_p)]


class _Detector:
    """AprilTag 3's detector with OpenCV dictionaries as its families (one detector, every
    family, as AprilTag 3 reads several); ``detect`` answers ``(dictionary, id, corners in
    AprilTag's order and convention, hamming)`` per code."""

    def __init__(self, dictionaries: tuple[str, ...], defaults: bool) -> None:
        from pupil_apriltags.bindings import (  # deferred: optional
            _ApriltagDetector,
            _ImageU8,
            _ZArray,
        )

        base = apriltag_detector("tag36h11", defaults)  # its library, and its settings
        self._lib = lib = base.libc
        lib.apriltag_detector_create.restype = ctypes.POINTER(_ApriltagDetector)
        lib.apriltag_detector_add_family_bits.argtypes = [
            ctypes.POINTER(_ApriltagDetector), ctypes.POINTER(_Family), ctypes.c_int]
        lib.apriltag_detector_add_family_bits.restype = None
        lib.image_u8_create.restype = ctypes.POINTER(_ImageU8)
        lib.apriltag_detector_detect.restype = ctypes.POINTER(_ZArray)
        self._td = td = lib.apriltag_detector_create()
        self._keep: list[Any] = []   # the tables AprilTag reads, alive as long as it
        for name in dictionaries:
            codes, pos, n, correct = aruco_family_bits(name)
            arrays = ((ctypes.c_uint64 * len(codes))(*[int(c) for c in codes]),
                      (ctypes.c_uint32 * len(pos))(*[p[0] for p in pos]),
                      (ctypes.c_uint32 * len(pos))(*[p[1] for p in pos]), name.encode())
            fam = _Family(len(codes), arrays[0], n + 2, n + 4, False, n * n, arrays[1],
                          arrays[2], 0, arrays[3], None)
            self._keep.append((fam, arrays))
            lib.apriltag_detector_add_family_bits(td, ctypes.byref(fam), correct)
        mine = base.tag_detector_ptr.contents
        td.contents.nthreads = mine.nthreads
        td.contents.quad_decimate = mine.quad_decimate
        td.contents.quad_sigma = mine.quad_sigma
        td.contents.refine_edges = mine.refine_edges
        td.contents.decode_sharpening = mine.decode_sharpening
        td.contents.debug = 0

    def detect(self, gray: np.ndarray) -> list[tuple[str, int, np.ndarray, int]]:
        from pupil_apriltags.bindings import _ApriltagDetection, zarray_get  # deferred: optional

        lib = self._lib
        h, w = gray.shape
        img = lib.image_u8_create(ctypes.c_int(w), ctypes.c_int(h))
        try:
            stride = img.contents.stride
            buf = np.ctypeslib.as_array(
                ctypes.cast(img.contents.buf, ctypes.POINTER(ctypes.c_uint8)), (h, stride))
            buf[:, :w] = gray
            found = lib.apriltag_detector_detect(self._td, img)
        finally:
            lib.image_u8_destroy(img)
        out = []
        try:
            for i in range(found.contents.size):
                p = ctypes.POINTER(_ApriltagDetection)()
                zarray_get(found, i, ctypes.byref(p))
                d = p.contents
                fam = ctypes.cast(d.family, ctypes.POINTER(_Family)).contents
                out.append((fam.name.decode(), int(d.id),
                            np.array([[d.p[k][0], d.p[k][1]] for k in range(4)]),
                            int(d.hamming)))
        finally:
            lib.apriltag_detections_destroy(found)
        return out


# ------------------------------------------------------------------ one reader
@dataclass(frozen=True)
class AprilTagCode:
    """A code AprilTag 3 read.

    Args:
        dictionary: The OpenCV dictionary it belongs to.
        marker_id: Its id in the dictionary.
        corners: (4, 2) corners, px, in OpenCV's order (TL, TR, BR, BL of the printed
            code) and pixel convention (pixel centres at integers).
        hamming: Bits corrected.
    """

    dictionary: str
    marker_id: int
    corners: np.ndarray
    hamming: int


_READERS: dict[tuple[tuple[str, ...], bool], _Detector] = {}


class AprilTagReader:
    """AprilTag 3 reading OpenCV dictionaries, each as a family built from OpenCV's table
    (an AprilTag dictionary's is AprilTag's own table, bit for bit), all in one detector.

    Args:
        dictionaries: OpenCV dictionary names (``DICT_6X6_250``, ``DICT_APRILTAG_36h11``).
        defaults: pupil-apriltags' default settings (decimate 2) instead of the study's
            (decimate 1, one thread).

    Raises:
        ImportError: pupil-apriltags is not installed.
    """

    def __init__(self, dictionaries: str | tuple[str, ...] | list[str],
                 defaults: bool = False) -> None:
        names = (dictionaries,) if isinstance(dictionaries, str) else tuple(dictionaries)
        self.dictionaries = tuple(sorted(set(names)))
        key = (self.dictionaries, defaults)
        if key not in _READERS:
            _READERS[key] = _Detector(self.dictionaries, defaults)
        self._detector = _READERS[key]

    def detect(self, gray: np.ndarray) -> list[AprilTagCode]:
        """The codes in a (H, W) uint8 grey image."""
        return [AprilTagCode(name, mid, corners[_TO_OPENCV_ORDER] - APRILTAG_PIXEL_OFFSET, ham)
                for name, mid, corners, ham in self._detector.detect(
                    np.ascontiguousarray(gray, np.uint8))]


def apriltag_reader(dictionaries: str | tuple[str, ...] | list[str], defaults: bool = False
                    ) -> AprilTagReader:
    """AprilTag 3 for ``dictionaries`` (any of OpenCV's), at the study's settings (decimate
    1, one thread) or pupil-apriltags' defaults (:class:`AprilTagReader`)."""
    return AprilTagReader(dictionaries, defaults)
