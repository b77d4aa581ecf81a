"""Drovisio: local positioning for builder drones (brick poses from colour dots and ArUco
codes)."""

import os as _os

from drovisio.errors import LIMITS as _LIMITS

# Before OpenCV's first use: its FFmpeg backend prints decoder chatter for every damaged frame
# and its image decoders log malformed headers (Drovisio reports such frames itself, one line
# each, in plain words); its decoders also get the pixel cap of drovisio.images.
_os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
_os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
_os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(_LIMITS.max_image_pixels))
