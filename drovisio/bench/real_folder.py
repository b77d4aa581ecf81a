"""What a folder of real photos holds (``drovisio bench real``): its pictures, its camera
file, the dictionary of its codes, a ChArUco board guessed from them, and so its kind
(tags, ChArUco or chessboard).

A folder is read once, by :func:`read_photos`, whatever its kind: every picture through the
project's one image reader, all of one size (one camera file is for one size), at most
:data:`MAX_IMAGES` of them, and all of them held at once only within the work cap. Its camera
file is read and fitted to that size by :func:`folder_camera`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.camera_file import NotACameraFile, load_camera
from drovisio.errors import LIMITS, InputError
from drovisio.images import IMAGE_SUFFIXES, ImageError, is_image_file, read_image
from drovisio.layout import aruco_dictionary_id
from drovisio.sources.folders import folder_entries

__all__ = ["CAMERA_SUFFIXES", "CHESS_SIZES", "MAX_IMAGES", "TAG_DICTIONARIES", "PhotoSet",
           "aruco_detector", "best_dictionary", "camera_files", "detect_kind", "folder_camera",
           "guess_charuco", "load_reference", "photos", "read_gray", "read_photos", "say"]

#: what a camera file of a folder may be called (OpenCV FileStorage, ROS camera_info)
CAMERA_SUFFIXES = (".yaml", ".yml", ".xml", ".json")
#: dictionaries tried on tag photos, most specific first
TAG_DICTIONARIES = ("DICT_APRILTAG_36h11", "DICT_APRILTAG_25h9", "DICT_APRILTAG_16h5",
                    "DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_250",
                    "DICT_ARUCO_ORIGINAL")
#: chessboard sizes (inner corners) tried when a set says none
CHESS_SIZES = ((9, 6), (8, 6), (7, 6), (7, 5), (5, 7), (6, 9), (6, 8), (10, 7), (11, 8),
               (6, 4), (8, 5), (4, 6), (5, 4))
MAX_IMAGES = 200


def say(line: str) -> None:
    """A note or a progress line of the bench, on stderr (the figures go to stdout)."""
    print(line, file=sys.stderr, flush=True)


def photos(folder: Path) -> list[Path]:
    """The folder's pictures in name order (hidden files skipped), all of them."""
    return folder_entries(folder, is_image_file)


@dataclass
class PhotoSet:
    """A folder's pictures, each read once as (H, W) uint8 grey, all of one size.

    Attributes:
        folder: The folder.
        paths: The pictures used, in name order.
        grays: Their pixels, in the same order.
    """

    folder: Path
    paths: list[Path]
    grays: list[np.ndarray]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of every picture."""
        return self.grays[0].shape[1], self.grays[0].shape[0]

    def done(self, k: int, what: str = "photos") -> None:
        """Say the progress once ``k`` of the photos are measured: a line at each tenth of
        them (by count, so that a long folder is seen to move), and at the last."""
        n = len(self.paths)
        if k == n or k * 10 // n != (k - 1) * 10 // n:
            say(f"  ... {self.folder}: {k} of {n} {what} done")


def read_photos(folder: Path) -> PhotoSet:
    """The folder's pictures (at most :data:`MAX_IMAGES`, the first in name order; the rest
    said in one line), read by the project's one image reader, each checked to be of the
    first one's size, and all of them held at once only within the work cap
    (:attr:`~drovisio.errors.Limits.max_work_bytes`), estimated from the first before the
    others are decoded.

    Raises:
        InputError: no pictures, one that cannot be read, one of another size, or too many
            to hold: one line naming the file and what to do.
    """
    paths = photos(folder)
    if not paths:
        raise InputError(f"{folder}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in the "
                         "folder; give a folder of photos")
    if len(paths) > MAX_IMAGES:
        say(f"{folder}: {len(paths)} pictures; the first {MAX_IMAGES} in name order are used "
            f"(from {paths[0].name} to {paths[MAX_IMAGES - 1].name})")
        paths = paths[:MAX_IMAGES]
    first = read_gray(paths[0])
    h, w = first.shape
    need = len(paths) * w * h
    if need > LIMITS.max_work_bytes:
        raise InputError(f"{folder}: {len(paths)} pictures of {w}x{h} held at once need "
                         f"{need / 2**30:.1f} GiB, more than the "
                         f"{LIMITS.max_work_bytes / 2**30:.1f} GiB cap; give fewer or smaller "
                         "pictures (DROVISIO_MAX_WORK_MIB raises the cap)")
    grays = [first]
    for p in paths[1:]:
        g = read_gray(p)
        if g.shape != first.shape:
            raise InputError(f"{p}: {g.shape[1]}x{g.shape[0]}, but {paths[0].name} is {w}x{h}:"
                             " the photos of one folder must be of one size (one camera "
                             "file is for one size); move it to a folder of its own")
        grays.append(g)
    return PhotoSet(folder, paths, grays)


def camera_files(folder: Path) -> list[Path]:
    """The folder's camera files by suffix (:data:`CAMERA_SUFFIXES`), in name order."""
    return folder_entries(folder, lambda p: p.suffix.lower() in CAMERA_SUFFIXES)


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


def detect_kind(photos: PhotoSet) -> str:
    """``chessboard``, ``charuco`` or ``tags`` (module doc); InputError when none fits."""
    folder = photos.folder
    if any(folder.glob("*.dat")):
        return "chessboard"
    grays = photos.grays[:3]
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
    """The folder's camera file (the first in name order) and its camera, or (None, None).

    A file of a camera suffix that holds no camera at all (a detector's parameters, a JSON
    report) is passed over; one that is a camera file but cannot be used is refused, never
    passed over for another or for none: the figures would be against a reference the user
    did not mean.

    Raises:
        InputError: a camera file that cannot be used (its own one line, and to fix it or
            remove it from the folder), or none and one is ``required``.
    """
    files = camera_files(folder)
    for k, p in enumerate(files):
        try:
            camera = load_camera(p)
        except NotACameraFile:
            continue
        except InputError as e:
            raise InputError(f"{e}; fix it or remove it from the folder") from None
        others = [q.name for q in files[k + 1:] if _is_camera_file(q)]
        if others:   # which one the figures are against must not be a guess
            say(f"{folder}: camera files {p.name} and {', '.join(others)}; {p.name}, the first "
                "in name order, is used; keep only the photos' own camera file in the folder")
        return p, camera
    if required:
        raise InputError(f"{folder}: no camera file (camera.yaml, *.yml, *.xml, *.json); add "
                         "the camera file of these photos")
    return None, None


def _is_camera_file(p: Path) -> bool:
    """``p`` reads as a camera file (one that does not, for any reason, is no second one)."""
    try:
        load_camera(p)
    except InputError:
        return False
    return True


def folder_camera(photos: PhotoSet, required: bool) -> tuple[Path | None, Camera | None]:
    """The folder's camera file and its camera for the photos' size (:func:`load_reference`):
    a file that gives no size takes the photos' (its warning, when its principal point is
    far from their centre, said in one line).

    Raises:
        InputError: as :func:`load_reference`, or a file for another image size.
    """
    path, camera = load_reference(photos.folder, required)
    if path is None or camera is None:
        return None, None
    w, h = photos.size
    try:
        camera, note = camera.for_image(w, h)
    except ValueError:
        raise InputError(f"{path}: image_width, image_height: {camera.width}x{camera.height}, "
                         f"but the photos are {w}x{h}; give the camera file of these photos "
                         "(or photos of its size)") from None
    if note:
        say(f"{path}: {note}")
    return path, camera
