"""What a folder of real photos holds (``drovisio bench real``): its pictures, its camera
file, the dictionary of its codes, a ChArUco board guessed from them, and so its kind
(tags, ChArUco or chessboard)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.errors import InputError
from drovisio.images import ImageError, read_image
from drovisio.layout import aruco_dictionary_id

__all__ = ["CHESS_SIZES", "IMAGE_SUFFIXES", "MAX_IMAGES", "TAG_DICTIONARIES", "aruco_detector",
           "best_dictionary", "camera_files", "detect_kind", "guess_charuco", "photos",
           "load_reference", "read_gray"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: dictionaries tried on tag photos, most specific first
TAG_DICTIONARIES = ("DICT_APRILTAG_36h11", "DICT_APRILTAG_25h9", "DICT_APRILTAG_16h5",
                    "DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_250",
                    "DICT_ARUCO_ORIGINAL")
#: chessboard sizes (inner corners) tried when a set says none
CHESS_SIZES = ((9, 6), (8, 6), (7, 6), (7, 5), (5, 7), (6, 9), (6, 8), (10, 7), (11, 8),
               (6, 4), (8, 5), (4, 6), (5, 4))
MAX_IMAGES = 200


def photos(folder: Path) -> list[Path]:
    """The folder's pictures in name order (hidden files skipped), at most MAX_IMAGES."""
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                   and not p.name.startswith("."))
    return files[:MAX_IMAGES]


def camera_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file()
                  and p.suffix.lower() in (".yaml", ".yml", ".xml", ".json"))


def read_gray(path: Path) -> np.ndarray:
    """The picture as (H, W) uint8 grey, read by the project's one image reader (its size
    from the header checked before a pixel is decoded).

    Raises:
        InputError: it cannot be read as an image (why, and to remove it from the folder).
    """
    try:
        return read_image(path, gray=True)[0]
    except ImageError as e:
        raise InputError(f"{path}: {e}; or remove it from the folder") from None


def aruco_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    """OpenCV's plain ``ArucoDetector`` (default parameters) for a dictionary."""
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    return cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())


def best_dictionary(grays: list[np.ndarray]) -> tuple[str | None, int]:
    """The dictionary that reads most codes in ``grays``, and how many (None, 0: none)."""
    best, n_best = None, 0
    for name in TAG_DICTIONARIES:
        det = aruco_detector(name)
        n = 0
        for g in grays:
            _, ids, _ = det.detectMarkers(g)
            n += 0 if ids is None else len(ids)
        if n > n_best:
            best, n_best = name, n
    return best, n_best


def guess_charuco(gray: np.ndarray, dictionary: str, ids: np.ndarray, square: float,
                   marker: float) -> cv2.aruco.CharucoBoard | None:
    """The board (squares cols × rows) whose codes are ids 0..m-1 and that gives the most
    ChArUco corners on the photo."""
    m = int(ids.max()) + 1
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    best, n_best = None, 0
    for cols in range(3, 16):
        for rows in range(3, 16):
            if (cols * rows) // 2 != m:
                continue
            b = cv2.aruco.CharucoBoard((cols, rows), square, marker, d)
            cc, ci, _, _ = cv2.aruco.CharucoDetector(b).detectBoard(gray)
            n = 0 if ci is None else len(ci)
            if n > n_best:
                best, n_best = b, n
    return best if n_best >= 6 else None


def detect_kind(folder: Path) -> str:
    """``chessboard``, ``charuco`` or ``tags`` (module doc); InputError when none fits."""
    images = photos(folder)
    if not images:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
    if any(folder.glob("*.dat")):
        return "chessboard"
    grays = [read_gray(p) for p in images[:3]]
    dictionary, n = best_dictionary(grays)
    if dictionary is not None and n > 0:
        if "APRILTAG" not in dictionary:
            _, ids, _ = aruco_detector(dictionary).detectMarkers(grays[0])
            if ids is not None and guess_charuco(grays[0], dictionary, np.ravel(ids),
                                                  0.04, 0.02) is not None:
                return "charuco"
        return "tags"
    for size in CHESS_SIZES:
        found, _ = cv2.findChessboardCorners(grays[0], size, None,
                                             cv2.CALIB_CB_ADAPTIVE_THRESH
                                             | cv2.CALIB_CB_NORMALIZE_IMAGE
                                             | cv2.CALIB_CB_FAST_CHECK)
        if found:
            return "chessboard"
    raise InputError(f"{folder}: neither codes nor a chessboard found in its first images "
                     "(give a folder of tag, ChArUco or chessboard photos)")


def load_reference(folder: Path, required: bool) -> tuple[Path | None, Camera | None]:
    """The folder's camera file (the first one that loads) and its camera, or (None, None).

    Raises:
        InputError: none loads and one is ``required``.
    """
    errors = []
    for p in camera_files(folder):
        try:
            return p, load_camera(p)
        except InputError as e:
            errors.append(str(e))
    if required:
        raise InputError(f"{folder}: no camera file that loads (camera.yaml, *.yml); "
                         + (errors[0] if errors else "add the camera file of these photos"))
    return None, None
