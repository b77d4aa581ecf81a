"""The calibration page's pictures: decoding an upload, JPEG and PNG encoding, the detected
corners drawn over a frame, and a kept view's thumbnail."""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec, Detection
from drovisio.images import ImageError, decode_image

__all__ = ["THUMB_WIDTH", "decode", "draw_corners", "jpeg", "png", "thumbnail_jpeg"]

THUMB_WIDTH = 200  # pixels
Colour = tuple[int, int, int]  # BGR


def decode(data: bytes, name: str = "") -> tuple[np.ndarray | None, str | None]:
    """(BGR image (H, W, 3) uint8, None), or (None, why it cannot be used) in plain words."""
    try:
        return decode_image(data, name)[0], None
    except ImageError as e:
        return None, str(e)


def jpeg(img: np.ndarray, quality: int = 80) -> bytes:
    """``img`` (BGR uint8) as JPEG bytes."""
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover - OpenCV always encodes a BGR uint8 image
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def png(frame: np.ndarray) -> bytes:
    """``frame`` (BGR uint8) as a quickly compressed PNG (a kept camera view, lossless)."""
    _, buf = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return buf.tobytes()


def draw_corners(img: np.ndarray, board: BoardSpec, det: Detection | None,
                 colour: Colour = (0, 220, 0)) -> None:
    """Draw the detected corners (image pixels) on ``img`` in place: a full chessboard as
    OpenCV draws it, anything else as dots."""
    if det is None:
        return
    if board.kind == "chessboard" and det.n == board.n_corners:
        cv2.drawChessboardCorners(img, board.pattern_size,
                                  det.corners.astype(np.float32).reshape(-1, 1, 2), True)
    else:
        r = max(2, round(img.shape[1] / 200))
        for x, y in det.corners:
            cv2.circle(img, (round(x), round(y)), r, colour, -1, cv2.LINE_AA)


def thumbnail_jpeg(img: np.ndarray | None, board: BoardSpec, det: Detection) -> bytes:
    """A kept view, :data:`THUMB_WIDTH` wide, its corners drawn; with no image (not on disk
    yet, or unreadable) the corners alone on grey."""
    if img is None:
        img = np.full((det.image_size[1], det.image_size[0], 3), 200, np.uint8)
    draw_corners(img, board, det)
    scale = THUMB_WIDTH / img.shape[1]
    img = cv2.resize(img, (THUMB_WIDTH, max(1, round(img.shape[0] * scale))),
                     interpolation=cv2.INTER_AREA)
    return jpeg(img, 75)
