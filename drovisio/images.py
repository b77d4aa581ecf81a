"""Decoding the images users give (files, uploads): bounded, and converted to 8-bit BGR.

One place decides what an image is for the whole project: which file suffixes are images or
videos, how a file is decoded (OpenCV), how any pixel type becomes 8-bit BGR, and what is
refused and why. An image header is read before any pixel is decoded: one whose size exceeds
:attr:`drovisio.errors.Limits.max_image_pixels` (50 Mpx; ``DROVISIO_MAX_IMAGE_MPX``) is
refused without allocating it (a 65000×65000 JPEG of a few kilobytes would otherwise take
tens of gigabytes).

What the image libraries print while decoding (libpng's ``libpng error: ...``, libjpeg's
``Premature end of JPEG file``) is kept off the process's stderr and said in the image's own
one line instead (:func:`decode_image`).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import stat
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from drovisio.errors import LIMITS, InputError, one_line
from drovisio.textfile import unreachable

__all__ = [
    "IMAGE_SUFFIXES",
    "ImageError",
    "VIDEO_SUFFIXES",
    "check_frame_size",
    "decode_image",
    "header_size",
    "is_image_file",
    "is_video_file",
    "read_image",
    "to_bgr8",
    "video_header_size",
]

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm",
                            ".ppm", ".pnm", ".pbm", ".jp2", ".exr", ".hdr"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg",
                            ".wmv", ".mjpeg", ".mjpg", ".h264", ".ts"})


class ImageError(InputError):
    """An image that cannot be used; the message says why in plain words (callers add the
    file name)."""


def is_image_file(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() in IMAGE_SUFFIXES


def is_video_file(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from an image header without decoding it (Pillow reads the header
    only); None when the format is not one Pillow knows."""
    from PIL import Image

    if _is_radiance(data):  # Pillow does not know Radiance .hdr; OpenCV does
        return _radiance_size(data)
    # Pillow only reads the header here; Drovisio's own cap (decode_image) decides, with a
    # message that gives the size. Pillow's own limit stays as it is: it is process-wide and
    # guards every other decode (a mesh's textures), so a header beyond it is refused here.
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(io.BytesIO(data)) as im:
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as e:
        m = re.search(r"\((\d{1,30}) pixels\)", str(e))
        pixels = int(m.group(1)) if m else None
        if pixels is not None and pixels <= LIMITS.max_image_pixels:
            return None   # a cap raised above Pillow's: OpenCV, under the same cap, decides
        size = f"{pixels / 1e6:.0f} Mpx" if pixels is not None else "too large"
        raise ImageError(f"the image is {size}, more than the "
                         f"{LIMITS.max_image_pixels / 1e6:.0f} Mpx Drovisio decodes; resize it "
                         "(or set DROVISIO_MAX_IMAGE_MPX)") from None
    except Exception:  # noqa: BLE001 - unknown or broken header: OpenCV decides
        return None


def _is_radiance(data: bytes) -> bool:
    return data[:10] == b"#?RADIANCE" or data[:6] == b"#?RGBE"


def _radiance_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a Radiance .hdr header (``-Y H +X W`` after the blank line)."""
    head = data[:8192]
    end = head.find(b"\n\n")
    if end < 0:
        return None
    line = head[end + 2:].split(b"\n", 1)[0].split()
    if len(line) != 4 or not all(t.isdigit() and len(t) <= 9 for t in line[1::2]):
        return None
    dims = {line[0][-1:]: int(line[1]), line[2][-1:]: int(line[3])}
    if set(dims) != {b"X", b"Y"}:
        return None
    return dims[b"X"], dims[b"Y"]


_STDERR_LOCK = threading.Lock()
_stderr_sink: list = []   # one temporary file, reused by every decode (made on first use)
#: the decoders' own lines: libpng's errors and warnings, libjpeg's messages (their fixed
#: texts), libtiff's, and OpenCV's log lines from its image readers (loadsave, grfmt). Any
#: other line caught while decoding was another thread's and goes back to stderr as it was;
#: a generic "Warning:" or an OpenCV line from its camera code is never taken for the image's.
_LIBRARY_LINE = re.compile(
    r"(libpng (error|warning)|TIFFRead|TIFFFetch|"
    r"\[ *(WARN|ERROR)[^\]]*\].*(imdecode|imread|loadsave|grfmt)|"
    r"(Premature end of JPEG|Corrupt JPEG data|Invalid JPEG|Not a JPEG file|Bogus (marker|"
    r"Huffman|DQT|DHT|sampling|input colorspace|message code)|Huffman table|Quantization "
    r"table|Unsupported JPEG|JPEG datastream|Inconsistent progression|Invalid SOS|Warning: "
    r"unknown JFIF|Suspension not allowed|Unsupported marker))")


@contextlib.contextmanager
def _library_messages() -> Iterator[list[str]]:
    """The lines the C libraries under OpenCV write to file descriptor 2 while the block runs,
    kept out of the process's stderr (one decode at a time: the descriptor is the process's).
    Where descriptor 2 cannot be redirected, nothing is caught and the block runs as is."""
    said: list[str] = []
    with _STDERR_LOCK:
        try:
            if not _stderr_sink:
                _stderr_sink.append(tempfile.TemporaryFile())
            sink = _stderr_sink[0]
            sink.seek(0)
            sink.truncate()
            if sys.stderr is not None:
                sys.stderr.flush()
            saved: int | None = os.dup(2)
        except (OSError, ValueError):
            saved = None
        if saved is None:
            yield said
            return
        try:
            os.dup2(sink.fileno(), 2)
            yield said
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            others: list[bytes] = []
            for line in sink:   # everything caught: another thread's lines are all given back
                text = line.decode("utf-8", "replace").strip()
                if _LIBRARY_LINE.match(text):
                    if len(said) < 8:   # the image's line says the first few
                        said.append(text)
                elif text:
                    others.append(line)
            if others:
                with contextlib.suppress(OSError):
                    os.write(2, b"".join(others))


def _decode_through_file(data: bytes, suffix: str) -> np.ndarray | None:
    """Decode a format OpenCV cannot decode from memory (Radiance .hdr) through our own
    temporary file, removed whatever happens (OpenCV's own copy is left in /tmp when its
    decoder fails)."""
    import tempfile

    import cv2

    fd, name = tempfile.mkstemp(prefix="drovisio-decode-", suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        try:
            return cv2.imread(name, cv2.IMREAD_UNCHANGED)
        except cv2.error:
            return None
    finally:
        os.unlink(name)


def to_bgr8(img: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Any image OpenCV reads (grey, BGRA, 16-bit, float) as BGR uint8, and notes on what was
    converted.

    16-bit images are scaled by the bit depth they actually use (a 12-bit camera's 0..4095 maps
    to 0..255, not to 0..15); float images in [0, 1] are multiplied by 255.

    Raises:
        ImageError: a pixel type or shape that is not an image.
    """
    notes: list[str] = []
    a = np.asarray(img)
    if a.size == 0:
        raise ImageError("the image has no pixels")
    if a.dtype == np.uint8:
        pass
    elif a.dtype in (np.uint16, np.int16, np.uint32, np.int32):
        top = int(a.max())
        bits = max(8, int(top).bit_length())
        full = (1 << bits) - 1
        notes.append(f"{a.dtype.itemsize * 8}-bit image ({bits} bits used) scaled to 8 bits")
        a = np.clip(np.rint(a.astype(np.float64) * (255.0 / full)), 0, 255).astype(np.uint8)
    elif np.issubdtype(a.dtype, np.floating):
        finite = a[np.isfinite(a)]
        peak = float(finite.max()) if finite.size else 1.0
        scale = 255.0 if peak <= 1.0 else 255.0 / peak
        notes.append(f"floating-point image scaled to 8 bits (x{scale:.4g})")
        a = np.clip(np.rint(np.nan_to_num(a) * scale), 0, 255).astype(np.uint8)
    else:
        raise ImageError(f"unsupported pixel type {a.dtype}")
    import cv2

    if a.ndim == 2:
        notes.append("greyscale image converted to BGR")
        a = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    elif a.ndim == 3 and a.shape[2] == 1:
        notes.append("greyscale image converted to BGR")
        a = cv2.cvtColor(a[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif a.ndim == 3 and a.shape[2] == 4:
        a = cv2.cvtColor(a, cv2.COLOR_BGRA2BGR)
    elif a.ndim == 3 and a.shape[2] == 2:
        notes.append("grey+alpha image converted to BGR")
        a = cv2.cvtColor(a[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif not (a.ndim == 3 and a.shape[2] == 3):
        raise ImageError(f"unsupported image shape {a.shape}")
    return np.ascontiguousarray(a), notes


def decode_image(data: bytes, name: str = "", *, gray: bool = False
                 ) -> tuple[np.ndarray, list[str]]:
    """Decode an image file's bytes to BGR uint8 (or grey).

    Args:
        data: The file's content.
        name: Its name (only its suffix is used, to recognise a truncated JPEG).
        gray: Decode to (H, W) uint8 grey, as OpenCV's ``IMREAD_GRAYSCALE`` does (a JPEG's
            luma as stored, not converted back from colour).

    Returns:
        (image, notes on conversions).

    Raises:
        ImageError: empty, truncated, too large, or not an image (the message says which).
    """
    import cv2

    if not data:
        raise ImageError("the file is empty")
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00\r\n\t ").endswith(b"\xff\xd9"):
        raise ImageError("corrupt JPEG: the file is cut short (copy it again from the camera)")
    size = header_size(data)
    if size is not None:
        _check_size(*size)
    elif _is_radiance(data):
        raise ImageError("a Radiance .hdr file whose header gives no size; is it whole?")
    with _library_messages() as said:
        if _is_radiance(data):
            img = _decode_through_file(data, ".hdr")
        else:
            try:
                img = cv2.imdecode(np.frombuffer(data, np.uint8),
                                   cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED)
            except cv2.error:
                img = None
    why = one_line("; ".join(said), 200)
    if img is None or img.size == 0:
        raise ImageError("cannot be read as an image (corrupt, truncated or not an image"
                         + (f": {why})" if why else ")"))
    notes: list[str] = []
    if gray and img.ndim == 2 and img.dtype == np.uint8:
        out = np.ascontiguousarray(img)
    else:
        out, notes = to_bgr8(img)
        if gray:   # a Radiance file: decoded whole, then made grey
            out = cv2.cvtColor(out, cv2.COLOR_BGR2GRAY)
    if why:   # decoded all the same (libjpeg fills what is missing with grey)
        notes.insert(0, f"damaged image, decoded with the decoder's warning: {why}")
    return out, notes


def read_image(path: str | os.PathLike, *, gray: bool = False) -> tuple[np.ndarray, list[str]]:
    """Read one image file as BGR uint8 (``gray``: (H, W) grey, :func:`decode_image`):
    (image, notes).

    Raises:
        ImageError: missing, a folder or a pipe (never read: it could block), unreadable, or
            not a usable image.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as e:
        raise ImageError(unreachable(p, e)) from None
    if stat.S_ISDIR(st.st_mode):
        raise ImageError("is a folder")
    if not stat.S_ISREG(st.st_mode):
        raise ImageError("not a regular file (a pipe or a device)")
    cap = max_image_file_bytes()
    try:
        with open(p, "rb") as f:
            head = f.read(64 * 1024)
            size = header_size(head)  # the header before the body: nothing huge is read
            if size is not None:
                _check_size(*size)
            if st.st_size > cap:
                raise ImageError(f"the file is {st.st_size / 2**20:.0f} MiB, more than the "
                                 f"{cap / 2**20:.0f} MiB of the largest image Drovisio "
                                 "decodes; is it an image?")
            data = head + f.read(cap + 1 - len(head))
    except OSError as e:
        raise ImageError(f"cannot read: {e.strerror or e}") from None
    if len(data) > cap:
        raise ImageError(f"the file grew past {cap / 2**20:.0f} MiB while being read")
    return decode_image(data, p.name, gray=gray)


def max_image_file_bytes() -> int:
    """Largest image file read: the largest image Drovisio decodes, uncompressed, at 16 bits
    and 4 channels (8 bytes a pixel), and never less than 64 MiB."""
    return max(LIMITS.max_image_pixels * 8, 64 * 2**20)


def _check_size(w: int, h: int) -> None:
    if w <= 0 or h <= 0:
        raise ImageError(f"the image header gives an empty size {w}x{h}")
    if w * h > LIMITS.max_image_pixels or max(w, h) > LIMITS.max_image_side:
        raise ImageError(f"the image is {w}x{h} ({w * h / 1e6:.0f} Mpx), more than the "
                         f"{LIMITS.max_image_pixels / 1e6:.0f} Mpx Drovisio decodes; "
                         "resize it (or set DROVISIO_MAX_IMAGE_MPX)")


def check_frame_size(w: int, h: int) -> None:
    """Refuse a frame size over the image caps (:attr:`~drovisio.errors.Limits.max_image_pixels`
    and ``max_image_side``), before any pixel of it is allocated.

    Raises:
        ImageError: the size and the cap, in one line.
    """
    _check_size(w, h)


#: most top-level MP4/MOV boxes walked, and most bytes of a ``moov`` box read, when looking
#: for the frame size (a hostile file may announce millions of boxes)
_MP4_MAX_BOXES = 64
_MP4_MAX_MOOV_BYTES = 16 * 2**20


def video_header_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """The largest frame size (width, height, pixels) a video's container announces, read
    from its header without decoding: AVI (``avih`` and the video stream's
    ``BITMAPINFOHEADER``) and MP4/MOV (each track's ``tkhd``). None when the container is
    another one or the header cannot be parsed (the decoder's own size is checked after
    opening, before the first frame is read).
    """
    import struct

    try:
        with open(path, "rb") as f:
            head = f.read(64 * 1024)
            if head[:4] == b"RIFF" and head[8:12] == b"AVI ":
                return _avi_size(head, struct)
            if head[4:8] in (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip"):
                return _mp4_size(f, struct)
    except (OSError, struct.error, ValueError):
        return None
    return None


def _avi_size(head: bytes, struct) -> tuple[int, int] | None:
    sizes: list[tuple[int, int]] = []
    i = head.find(b"avih")
    if i >= 0 and len(head) >= i + 48:
        w, h = struct.unpack_from("<II", head, i + 8 + 32)
        sizes.append((w, h))
    i = head.find(b"strf")
    if i >= 0 and len(head) >= i + 20:
        w, h = struct.unpack_from("<ii", head, i + 8 + 4)  # BITMAPINFOHEADER biWidth/biHeight
        sizes.append((abs(w), abs(h)))
    return max(sizes, key=lambda s: s[0] * s[1]) if sizes else None


def _mp4_size(f, struct) -> tuple[int, int] | None:
    f.seek(0, os.SEEK_END)
    end = f.tell()
    pos = 0
    for _ in range(_MP4_MAX_BOXES):
        if pos + 8 > end:
            return None
        f.seek(pos)
        size, kind = struct.unpack(">I4s", f.read(8))
        body = pos + 8
        if size == 1:
            size = struct.unpack(">Q", f.read(8))[0]
            body += 8
        elif size == 0:
            size = end - pos
        if size < body - pos:
            return None
        if kind == b"moov":
            moov = f.read(min(size - (body - pos), _MP4_MAX_MOOV_BYTES))
            return _tkhd_size(moov, struct)
        pos += size
    return None


def _tkhd_size(moov: bytes, struct) -> tuple[int, int] | None:
    best: tuple[int, int] | None = None
    i = moov.find(b"tkhd")
    while i >= 0:
        version = moov[i + 4] if len(moov) > i + 4 else 0
        # version, flags, times and ids (v0: 20 bytes after them, v1: 32), reserved, layer,
        # group, volume, reserved, matrix: width and height are 16.16 fixed point at the end
        at = i + 4 + 4 + (32 if version == 1 else 20) + 8 + 8 + 36
        if len(moov) >= at + 8:
            w, h = struct.unpack_from(">II", moov, at)
            size = (w >> 16, h >> 16)
            if best is None or size[0] * size[1] > best[0] * best[1]:
                best = size
        i = moov.find(b"tkhd", i + 4)
    return best
