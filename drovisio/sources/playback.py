"""Still images played as if a camera filmed them (the calibration page's sample session)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from drovisio.images import ImageError, is_video_file, read_image
from drovisio.raw_frame import RawFrame
from drovisio.sources.folders import list_folder

__all__ = ["PlaybackReader"]


class PlaybackReader:
    """Still images played as if a camera filmed them, looping, at up to ``fps`` frames per
    second (the calibration page's sample session, or a folder of calibration photos).

    Each image is one board placement, held for ``seconds_per_view``: first the board "moves"
    there (a quarter of the time: a blurred blend sliding from the previous image), then it is
    held still (the image itself, shifted by a random sub-pixel jitter, with a little sensor
    noise), so that the sharpness and stillness gates see what a real camera would give. On a
    busy machine a placement is held for at least ``min_still_frames`` frames, so that no
    placement is skipped however slowly frames are processed (``lossless``: the consumer's
    pace drives it).
    """

    MOVE_FRACTION = 0.25
    finite = False
    lossless = True

    def __init__(self, files: list[Path], seconds_per_view: float = 1.5, fps: float = 12.0,
                 seed: int = 0, label: str = "sample session", min_still_frames: int = 3
                 ) -> None:
        if not files:
            raise OSError("no images to play")
        self.files = list(files)
        spv = max(0.05, float(seconds_per_view))
        self.move_s = self.MOVE_FRACTION * spv
        self.still_s = spv - self.move_s
        self.min_still = max(2, int(min_still_frames))
        self.period = 1.0 / max(1.0, float(fps))
        self.label = label
        self._rng = np.random.default_rng(seed)
        # a few precomputed noise fields (drawing fresh Gaussian noise costs more than the rest)
        self._noise: list[np.ndarray] = []
        self._next = time.monotonic()
        self._k = 0                # index of the placement shown
        self._moving = False       # first placement: already there
        self._since = time.monotonic()
        self._n = 0                # frames given in the current phase
        self._count = 0
        self._cache: dict[int, np.ndarray] = {}

    @classmethod
    def from_folder(cls, folder: Path, **kw) -> PlaybackReader:
        files = [f for f in list_folder(Path(folder)) if not is_video_file(f)]
        return cls(files, label=kw.pop("label", f"images in {folder}"), **kw)

    def open(self) -> None:
        pass

    def _image(self, k: int) -> np.ndarray:
        k %= len(self.files)
        if k not in self._cache:
            if len(self._cache) >= 2:  # only the current and the previous placement are kept
                self._cache.pop(next(iter(self._cache)))
            try:
                self._cache[k] = read_image(self.files[k])[0]
            except ImageError as e:
                raise OSError(f"cannot read {self.files[k]}: {e}") from None
        return self._cache[k]

    def _advance(self, now: float) -> None:
        if self._moving:
            if now - self._since >= self.move_s and self._n >= 1:
                self._moving, self._since, self._n = False, now, 0
        elif now - self._since >= self.still_s and self._n >= self.min_still:
            self._k += 1
            self._moving, self._since, self._n = True, now, 0

    def _noisy(self, img: np.ndarray) -> np.ndarray:
        if not self._noise or self._noise[0].shape != img.shape:
            self._noise = [np.round(self._rng.normal(0.0, 1.5, img.shape)).astype(np.int16)
                           for _ in range(3)]
        noise = self._noise[int(self._rng.integers(len(self._noise)))]
        return np.clip(img.astype(np.int16) + noise, 0, 255).astype(np.uint8)

    def _picture(self, now: float) -> np.ndarray:
        import cv2  # deferred: heavy (`drovisio --help` must not load it)

        cur = self._image(self._k)
        h, w = cur.shape[:2]
        if self._moving:
            prev = self._image(self._k - 1)
            if prev.shape != cur.shape:
                prev = cv2.resize(prev, (w, h))
            a = min(1.0, (now - self._since) / self.move_s, 0.5 * self._n)
            mixed = cv2.addWeighted(prev, 1.0 - a, cur, a, 0.0)
            dx = 4.0 + (1.0 - a) * 12.0
            m = np.array([[1, 0, dx], [0, 1, 0.3 * dx]], np.float32)
            mixed = cv2.warpAffine(mixed, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
            return cv2.blur(mixed, (17, 1))  # horizontal motion blur
        dx, dy = self._rng.uniform(-0.2, 0.2, 2)
        m = np.array([[1, 0, dx], [0, 1, dy]], np.float32)
        img = cv2.warpAffine(cur, m, (w, h), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        return self._noisy(img)

    def read(self) -> RawFrame | None:
        now = time.monotonic()
        if self._next > now:
            time.sleep(self._next - now)
        now = time.monotonic()
        self._next = max(self._next + self.period, now)
        self._advance(now)
        self._n += 1
        try:
            img = self._picture(now)
        except OSError:
            return None
        self._count += 1
        return RawFrame(img, self._count - 1, name=self.files[self._k % len(self.files)].name)

    def close(self) -> None:
        self._cache.clear()


