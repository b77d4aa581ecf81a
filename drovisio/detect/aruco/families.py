"""The code families the layouts use: one OpenCV detector per family over a dictionary of
exactly our ids, and what the later stages need to read those codes.

A *family* is a set of dictionaries that share their codes (``DICT_4X4_50`` and
``DICT_4X4_1000``): one pass of OpenCV's detector per family, with a dictionary made of
exactly the ids the loaded layouts own (fewer false decodes). Per family this module also
prepares every id's inner bits in the four quarter turns (the rescue matches readings against
them), the bit errors a rescued reading may have, the budget of the second look, and whether
the family's cells are small enough for the ring quads and the second look.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco.codes import CodeOwner
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.code_reading import CodeReader
from drovisio.layout import (
    MarkerLayout,
    aruco_code_bits,
    aruco_dictionary_id,
    aruco_dictionary_size,
    aruco_family,
)

__all__ = [
    "CodeFamily",
    "chance_bit_errors",
    "code_families",
    "detector_parameters",
    "plain_detector",
    "tolerable_bit_errors",
]


@functools.lru_cache(maxsize=8)
def _reader(n: int) -> CodeReader:
    return CodeReader(n)


@dataclass
class CodeFamily:
    """The codes of one dictionary family that the layouts own, and their detectors."""

    dvalue: int
    """The ``cv2.aruco`` constant of the family's largest dictionary the layouts name."""
    detector: cv2.aruco.ArucoDetector
    """OpenCV's detector over a dictionary of exactly :attr:`ids`."""
    ids: np.ndarray
    """(N,) int64, our ids, sorted (OpenCV's index into its dictionary)."""
    owners: dict[int, CodeOwner]
    """Code id -> (layout, instance, slot)."""
    patterns: np.ndarray
    """(4, N, bits) int8: the inner bits of every id in the four corner orders a quad can be
    read in; ``patterns[k]`` is the code rotated by -k quarter turns (``np.rot90``)."""
    rescue_errors: int
    """Most bits a rescued reading may have wrong (:func:`tolerable_bit_errors`)."""
    look_errors: int
    """Most bits an unread quad may be off and still get a second look
    (:func:`chance_bit_errors` at ``second_look_chance``)."""
    small_cells: bool
    """Cells of a 20-px code are at most ``small_cell_px`` wide: the family gets the ring
    quads and the second look."""
    reader: CodeReader
    """The least-squares reader of the family's code size."""
    second_detector: cv2.aruco.ArucoDetector | None = None
    """OpenCV's detector of the second look (built on first use)."""


def plain_detector(dictionary_name: str = "DICT_4X4_50") -> cv2.aruco.ArucoDetector:
    """OpenCV's ``ArucoDetector`` with default parameters (the benchmark's reference)."""
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary_name))
    return cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())


def detector_parameters(params: ArucoParams, camera: Camera) -> cv2.aruco.DetectorParameters:
    """OpenCV's parameters of the first pass (see :class:`ArucoParams`, first group)."""
    p = cv2.aruco.DetectorParameters()
    w = int(params.adaptive_window) | 1
    p.adaptiveThreshWinSizeMin = w
    p.adaptiveThreshWinSizeMax = w
    p.adaptiveThreshWinSizeStep = 10
    p.adaptiveThreshConstant = float(params.threshold_constant)
    p.perspectiveRemovePixelPerCell = int(params.pixels_per_cell)
    side = max(camera.width, camera.height)
    # OpenCV measures its contour, which lies inside the code by the inset the corner fit's
    # start undoes (initial_expand_px along each diagonal: sqrt(2) times that off each side)
    contour_px = params.min_code_px - np.sqrt(2.0) * params.initial_expand_px
    p.minMarkerPerimeterRate = float(4.0 * contour_px / side)
    p.errorCorrectionRate = float(params.error_correction_rate)
    p.polygonalApproxAccuracyRate = float(params.polygon_accuracy)
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    return p


def second_look_detector(family: CodeFamily, params: ArucoParams, camera: Camera
                         ) -> cv2.aruco.ArucoDetector:
    """OpenCV's detector of the second look for a family (a wider, softer threshold on the
    enlarged image), built once."""
    if family.second_detector is None:
        dp = detector_parameters(params, camera)
        dp.adaptiveThreshWinSizeMin = dp.adaptiveThreshWinSizeMax = params.second_look_window
        dp.adaptiveThreshConstant = float(params.second_look_constant)
        dp.minMarkerPerimeterRate = 0.05
        family.second_detector = cv2.aruco.ArucoDetector(
            family.detector.getDictionary(), dp, cv2.aruco.RefineParameters())
    return family.second_detector


def chance_bit_errors(pats: np.ndarray, chance: float) -> int:
    """Most bit errors e such that a random reading lands within e bits of one of the
    patterns (every id in every quarter turn) with a chance of at most ``chance``."""
    n = pats.shape[2]
    count = pats.shape[0] * pats.shape[1]
    e, total = -1, 0
    while e < n and (total + math.comb(n, e + 1)) * count / 2.0 ** n <= chance:
        e += 1
        total += math.comb(n, e)
    return e


def tolerable_bit_errors(pats: np.ndarray, params: ArucoParams) -> int:
    """Bit errors a rescued reading may have: at most a third of the smallest Hamming
    distance between two of our codes (any ids, any quarter turns, a code and its own
    turns included), so a reading that close to one code is twice as far from every
    other; and few enough that a random pattern (a quad on gravel) lands that close to
    one of them with a chance under ``rescue_chance_limit``. 4×4 codes get 0, 36h11 3."""
    P = pats.reshape(-1, pats.shape[2]).astype(np.int32)
    n = P.shape[1]
    d = (P[:, None, :] != P[None, :, :]).sum(axis=2)
    np.fill_diagonal(d, n)
    e = min(params.rescue_max_bit_errors, (int(d.min()) - 1) // 3)
    while e > 0 and (sum(math.comb(n, k) for k in range(e + 1)) * len(P) / 2.0 ** n
                     > params.rescue_chance_limit):
        e -= 1
    return max(e, 0)


@dataclass
class _FamilyIds:
    dictionary: str
    owners: dict[int, CodeOwner]


def _ids_by_family(layouts: Sequence[MarkerLayout]) -> list[_FamilyIds]:
    """Every code id of the layouts, by family; each family named by the largest of its
    dictionaries the layouts use."""
    fam: dict[str, _FamilyIds] = {}
    for lay in layouts:
        for slot, dname in lay.code_dictionaries().items():
            entry = fam.setdefault(aruco_family(dname), _FamilyIds(dname, {}))
            if aruco_dictionary_size(dname) > aruco_dictionary_size(entry.dictionary):
                entry.dictionary = dname
            for k in range(lay.instances or 0):
                entry.owners[lay.marker_id(k, slot)] = (lay, k, slot)
    return list(fam.values())


def code_families(layouts: Sequence[MarkerLayout], params: ArucoParams, camera: Camera
                  ) -> list[CodeFamily]:
    """The families of the layouts' codes, each with its detector and bit patterns."""
    out: list[CodeFamily] = []
    for entry in _ids_by_family(layouts):
        dvalue = aruco_dictionary_id(entry.dictionary)
        full = cv2.aruco.getPredefinedDictionary(dvalue)
        ids = np.array(sorted(i for i in entry.owners if i < full.bytesList.shape[0]),
                       np.int64)
        if ids.size == 0:
            continue
        sub = cv2.aruco.Dictionary(full.bytesList[ids].copy(), full.markerSize,
                                   full.maxCorrectionBits)
        det = cv2.aruco.ArucoDetector(sub, detector_parameters(params, camera),
                                      cv2.aruco.RefineParameters())
        inner = [aruco_code_bits(dvalue, int(i))[1:-1, 1:-1] > 0 for i in ids]
        pats = np.array([[np.rot90(b, -k).ravel() for b in inner] for k in range(4)], np.int8)
        out.append(CodeFamily(
            dvalue=dvalue, detector=det, ids=ids, owners=entry.owners, patterns=pats,
            rescue_errors=tolerable_bit_errors(pats, params),
            look_errors=chance_bit_errors(pats, params.second_look_chance),
            # the second look pays where a 20-px code's cells are small (6x6 and 36h11: 2.5
            # px; 4x4 codes: 3.3 px, read at the first pass)
            small_cells=20.0 / (full.markerSize + 2) <= params.small_cell_px,
            reader=_reader(full.markerSize + 2)))
    return out
