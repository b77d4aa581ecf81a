"""What the renderer paints: a texture maps plane coordinates (u, v), metres, to colours.

A :data:`Texture` takes (N,) arrays ``u``, ``v`` and returns (N, 3) BGR float32 colours and a
(N,) mask of the samples it covers (None: all of them).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import cv2
import numpy as np

from drovisio.synth.scene import CONCRETE, INK_BLACK, PAPER_WHITE, Board, Ground

__all__ = ["Texture", "solid", "code_texture", "disc_texture", "board_texture",
           "ground_texture", "ground_sampler"]

Texture = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray | None]]


def solid(bgr: Sequence[float]) -> Texture:
    c = np.asarray(bgr, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        return np.broadcast_to(c, (u.size, 3)), None
    return tex


def code_texture(bits: np.ndarray, size: float) -> Texture:
    """An ArUco code: ``bits`` (cells × cells, 0 = black) over [0, size]², paper outside."""
    cells = bits.shape[0]
    pal = np.array([INK_BLACK, PAPER_WHITE], np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        col = np.floor(u / size * cells).astype(np.int64)
        row = np.floor(v / size * cells).astype(np.int64)
        inside = (col >= 0) & (col < cells) & (row >= 0) & (row < cells)
        val = np.ones(u.size, np.int64)
        val[inside] = bits[row[inside], col[inside]]
        return pal[val], None
    return tex


def disc_texture(radius: float, bgr: Sequence[float]) -> Texture:
    c = np.asarray(bgr, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        return np.broadcast_to(c, (u.size, 3)), (u * u + v * v) <= radius * radius
    return tex


def _checker_texture(square: float) -> Texture:
    pal = np.array([INK_BLACK, PAPER_WHITE], np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        # u, v measured from the first inner corner; square (0, 0) is the one at +u, +v of it
        parity = (np.floor(u / square).astype(np.int64) + np.floor(v / square).astype(np.int64))
        return pal[(parity & 1)], None  # (0,0) square black: corner (0,0) has black at +u+v
    return tex


def board_texture(board: Board) -> Texture:
    sq = board.square
    checker = _checker_texture(sq)
    white = np.asarray(PAPER_WHITE, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        bgr, _ = checker(u, v)
        bgr = np.array(bgr)
        outside = (u < -sq) | (u > board.cols * sq) | (v < -sq) | (v > board.rows * sq)
        bgr[outside] = white
        return bgr, None
    return tex


def _noise(rng: np.random.Generator, size: int, scale: int, amp: float) -> np.ndarray:
    """Smooth noise: normal noise on a grid ``scale`` texels apart, cubic-interpolated."""
    small = rng.normal(0, 1, (size // scale, size // scale)).astype(np.float32)
    big = cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    return amp * big


def _concrete(rng: np.random.Generator, seed: int, size: int) -> np.ndarray:
    g = (140 + _noise(rng, size, 64, 10) + _noise(rng, size, 8, 6)
         + rng.normal(0, 4, (size, size)).astype(np.float32))
    return np.stack([g, g + 2, g + 5], axis=2)


def _gravel(rng: np.random.Generator, seed: int, size: int) -> np.ndarray:
    img = np.full((size, size, 3), 110, np.float32) + _noise(rng, size, 16, 10)[..., None]
    for _ in range(size * size // 90):
        c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
        ax = (int(rng.integers(2, 9)), int(rng.integers(2, 7)))
        tone = float(rng.uniform(60, 200))
        col = (tone * rng.uniform(0.85, 1.0), tone * rng.uniform(0.9, 1.05), tone)
        cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, col, -1,
                    lineType=cv2.LINE_AA)
    img += rng.normal(0, 6, img.shape).astype(np.float32)
    return img


def _grass(rng: np.random.Generator, seed: int, size: int) -> np.ndarray:
    img = np.zeros((size, size, 3), np.float32)
    img[:] = (40, 95, 60)
    img += _noise(rng, size, 32, 12)[..., None]
    for _ in range(size * size // 60):
        x, y = int(rng.integers(0, size)), int(rng.integers(0, size))
        ang = rng.uniform(0, 2 * math.pi)
        ln = rng.uniform(4, 14)
        g = float(rng.uniform(70, 170))
        col = (g * 0.35, g, g * 0.55)
        cv2.line(img, (x, y), (int(x + ln * math.cos(ang)), int(y + ln * math.sin(ang))),
                 col, 1, lineType=cv2.LINE_AA)
    img += rng.normal(0, 5, img.shape).astype(np.float32)
    return img


def _code_decoy(img: np.ndarray, rng: np.random.Generator, x: int, y: int, s: int) -> None:
    """Black and white blocks that look like a code (a detector's decoy)."""
    size = img.shape[0]
    n = int(rng.integers(4, 8))
    cell = max(2, s // n)
    blk = (rng.random((n, n)) < 0.5).astype(np.float32) * 210 + 20
    blk[0, :] = blk[-1, :] = blk[:, 0] = blk[:, -1] = 20
    patch = cv2.resize(blk, (n * cell, n * cell), interpolation=cv2.INTER_NEAREST)
    ye, xe = min(size, y + n * cell), min(size, x + n * cell)
    img[y:ye, x:xe] = patch[: ye - y, : xe - x, None].astype(np.uint8)


def _clutter_object(img: np.ndarray, rng: np.random.Generator) -> None:
    """One object of the clutter: a disc, a box, a line, a decoy code, text or a polygon."""
    size = img.shape[0]
    shape = rng.integers(0, 6)
    col: tuple[float, ...] = tuple(float(c) for c in rng.uniform(0, 255, 3))
    if rng.random() < 0.25:  # strong reds and blues: cups, tarpaulins, tape
        col = (40.0, 35.0, 200.0) if rng.random() < 0.5 else (190.0, 110.0, 30.0)
    x, y = int(rng.integers(0, size)), int(rng.integers(0, size))
    s = int(rng.integers(6, 60))
    if shape == 0:
        cv2.circle(img, (x, y), s // 2, col, -1, lineType=cv2.LINE_AA)
    elif shape == 1:
        cv2.rectangle(img, (x, y), (x + s, y + int(s * rng.uniform(0.3, 1.5))), col, -1)
    elif shape == 2:
        cv2.line(img, (x, y), (x + int(rng.integers(-80, 80)), y + int(
            rng.integers(-80, 80))), col, int(rng.integers(1, 5)), lineType=cv2.LINE_AA)
    elif shape == 3:
        _code_decoy(img, rng, x, y, s)
    elif shape == 4:
        cv2.putText(img, "".join(rng.choice(list("ABCDEFGH0123456789"), 4)), (x, y),
                    cv2.FONT_HERSHEY_SIMPLEX, float(rng.uniform(0.5, 2.0)), col,
                    int(rng.integers(1, 4)), cv2.LINE_AA)
    else:
        pts = rng.integers(-s, s, (5, 2)) + [x, y]
        cv2.fillConvexPoly(img, cv2.convexHull(pts.astype(np.int32)), col,
                           lineType=cv2.LINE_AA)


def _clutter(rng: np.random.Generator, seed: int, size: int) -> np.ndarray:
    img = np.clip(ground_texture("concrete", seed + 1, size), 0, 255).astype(np.uint8)
    for _ in range(140):
        _clutter_object(img, rng)
    return img.astype(np.float32) + rng.normal(0, 3, img.shape).astype(np.float32)


_GROUNDS: dict[str, Callable[[np.random.Generator, int, int], np.ndarray]] = {
    "concrete": _concrete, "gravel": _gravel, "grass": _grass, "clutter": _clutter,
}


def _tileable(img: np.ndarray) -> np.ndarray:
    """Make a texture tile without seams: blend it with itself shifted by half a tile,
    weighting the shifted copy fully at the tile's borders (where it is continuous across
    the wrap)."""
    size = img.shape[0]
    ramp = np.sin(np.pi * (np.arange(size) + 0.5) / size) ** 2
    w = (ramp[:, None] * ramp[None, :])[..., None].astype(np.float32)
    img = np.asarray(img, np.float32)
    return w * img + (1 - w) * np.roll(img, (size // 2, size // 2), axis=(0, 1))


@functools.lru_cache(maxsize=8)
def ground_texture(kind: str, seed: int, size: int = 1024) -> np.ndarray:
    """A procedural, tileable ground texture (BGR float32, ``size``²).

    Kinds: ``concrete`` (grey, mottled), ``gravel`` (pebbles), ``grass`` (green blades),
    ``clutter`` (a photo-like mess: coloured shapes including red and blue objects, black and
    white blocks that look like codes, text, lines), ``plain`` (uniform grey).
    """
    if kind == "plain":
        return np.full((size, size, 3), CONCRETE, np.float32)
    make = _GROUNDS.get(kind)
    if make is None:
        raise ValueError(f"unknown ground kind {kind!r}; use concrete, gravel, grass, clutter "
                         "or plain")
    img = _tileable(make(np.random.default_rng(seed), seed, size))
    out = np.clip(img, 0, 255).astype(np.float32)
    out.flags.writeable = False
    return out


def ground_sampler(ground: Ground) -> Texture:
    tex = ground_texture(ground.kind, ground.seed)
    n = tex.shape[0]
    scale = 1.0 / ground.metres_per_texel

    def sample(u: np.ndarray, v: np.ndarray):
        # bilinear, tiled; remap wants 2-D maps narrower than SHRT_MAX: fold into rows
        width = 2048
        rows = -(-u.size // width)
        pad = rows * width - u.size
        mx = np.pad(np.mod(u * scale, n), (0, pad)).astype(np.float32).reshape(rows, width)
        my = np.pad(np.mod(v * scale, n), (0, pad)).astype(np.float32).reshape(rows, width)
        out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out.reshape(-1, 3)[: u.size], None
    return sample

