"""Stage 2, the rescue: quads OpenCV found but could not read, read again by a fit.

The candidates are the quads OpenCV rejected and, for families with small cells in frames
where OpenCV read one of the family's codes, the quads of thresholded contours it passed over
(:func:`drovisio.detect.code_reading.ring_quads`: a code whose border merges with a pyramid's
shaded side). Each small, not too skewed candidate
away from the codes already read is read by :class:`drovisio.detect.code_reading.CodeReader`
(blur included) at a few outward shifts of its corners and in the four corner orders; an
unambiguous match to one of our ids within the family's tolerated bit errors is kept
(:func:`drovisio.detect.aruco.families.tolerable_bit_errors`). The quads still unread that
show a code's frame, or read closer to one of our codes than chance, go to the second look.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drovisio.detect.aruco.codes import CodeDetection
from drovisio.detect.aruco.families import CodeFamily
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.code_reading import ring_quads

__all__ = ["candidate_quads", "read_quads", "rescue_codes"]


def _no_quads() -> np.ndarray:
    return np.zeros((0, 4, 2))


def candidate_quads(gray: np.ndarray, rejected: Sequence[np.ndarray] | np.ndarray | None,
                    found: Sequence[np.ndarray], family: CodeFamily, params: ArucoParams
                    ) -> np.ndarray:
    """The quads worth reading again: OpenCV's rejected ones and the ring quads, small (8 px
    to ``rescue_max_side_px`` a side), not too skewed, away from the codes already found.

    Args:
        gray: (H, W) uint8 frame.
        rejected: OpenCV's rejected candidates (each 4 corners, px), or None.
        found: (4, 2) corners (px) of the family's codes already read.
        family: The code family.
        params: The detector's tuning (the rescue's group).

    Returns:
        (Q, 4, 2) corners, px, at most ``rescue_max``.
    """
    p = params
    quads = (np.asarray(rejected, np.float64).reshape(-1, 4, 2)
             if rejected is not None and len(rejected) else _no_quads())
    # ring quads only beside a code OpenCV read: a code whose border merges with a pyramid's
    # side sits on a brick whose other codes read; on frames with no code the contour pass
    # was most of the detector's time (4 of 10 ms on a street scene)
    if family.small_cells and p.ring_quads_max and len(found):
        rq = ring_quads(gray, p.adaptive_window, p.threshold_constant, 8.0,
                        p.rescue_max_side_px, p.ring_quads_max)
        quads = np.concatenate([quads, rq]) if len(rq) else quads
    if len(quads) == 0:
        return _no_quads()
    dq = quads - quads[:, [3, 0, 1, 2]]
    side = np.sqrt((dq * dq).sum(axis=2))
    # small quads only: OpenCV reads bigger codes itself (rescued codes on the bench
    # measured 12-25 px a side); not too skewed
    mean_side = side.mean(axis=1)
    keep = ((side.min(axis=1) >= 8.0) & (mean_side <= p.rescue_max_side_px)
            & (side.max(axis=1) <= 3.0 * side.min(axis=1)))
    if not keep.any():
        return _no_quads()
    if len(found):
        fc = np.asarray(found, np.float64).reshape(-1, 4, 2).sum(axis=1) * 0.25
        dd = quads.sum(axis=1)[:, None] * 0.25 - fc[None]
        dist = np.sqrt((dd * dd).sum(axis=2)).min(axis=1)
        keep &= dist > 0.5 * mean_side
    return quads[keep][: p.rescue_max]


def _hamming(gray: np.ndarray, quads: np.ndarray, family: CodeFamily, params: ArucoParams
             ) -> tuple[np.ndarray, np.ndarray]:
    """Hamming distances of each quad's readings (at every shift) to every pattern.

    Returns:
        (ham (Q, shifts, 4 · ids): bits off, 99 where the reading shows no code's frame;
        ok (Q, shifts): the reading has a code's contrast and uniform black cells).
    """
    p = params
    ctr = quads.mean(axis=1, keepdims=True)
    radial = quads - ctr
    radial /= np.sqrt((radial * radial).sum(axis=2, keepdims=True))
    shifts = p.rescue_shifts_px  # outward along the diagonals
    T = np.stack([quads + sh * radial for sh in shifts], axis=1)  # (Q, shifts, 4, 2)
    Q, S = len(quads), len(shifts)
    reading = family.reader.read(gray, T.reshape(-1, 4, 2))
    bits = reading.bits.reshape(Q, S, -1).astype(np.float32)
    pats = family.patterns  # (4 rotations, ids, bits)
    P = pats.reshape(-1, pats.shape[2]).astype(np.float32)  # (4 * ids, bits)
    ham = bits @ (1.0 - P).T + (1.0 - bits) @ P.T  # Hamming distances (Q, S, 4 * ids)
    ok = ((reading.contrast >= p.rescue_min_contrast)
          & (reading.black_offset <= p.rescue_max_black_offset)).reshape(Q, S)
    return np.where(ok[..., None], ham, 99), ok


def read_quads(gray: np.ndarray, quads: np.ndarray, family: CodeFamily, params: ArucoParams
               ) -> tuple[list[CodeDetection], np.ndarray]:
    """Read candidate quads and keep the unambiguous matches to our ids.

    Args:
        gray: (H, W) uint8 frame.
        quads: (Q, 4, 2) candidates, px.
        family: The code family (its reader, patterns and bit tolerances).
        params: The detector's tuning (the rescue's group).

    Returns:
        (the codes read, corners rolled so that the code is upright; the (U, 4, 2) quads
        still unread that deserve a second look).
    """
    ham, ok = _hamming(gray, quads, family, params)
    pat_ids = family.ids
    out: list[CodeDetection] = []
    read = np.zeros(len(quads), bool)
    A = len(pat_ids)
    tol = family.rescue_errors
    best = ham.min(axis=(1, 2))
    for q in np.nonzero(best <= tol)[0]:
        hits = np.argwhere(ham[q] == best[q])  # (shift, rotation * A + id index)
        if len({(int(pat_ids[j % A]), int(j // A)) for _, j in hits}) != 1:
            continue  # two codes (or turns) read equally well: not trusted
        _shift, j = hits[0]
        rot, mid = int(j // A), int(pat_ids[j % A])
        if any(c.marker_id == mid and np.abs(c.raw_corners.mean(axis=0)
                                             - quads[q].mean(axis=0)).max() < 3.0
               for c in out):
            read[q] = True
            continue  # the same code from OpenCV's quad and from a ring's hull
        lay, k, slot = family.owners[mid]
        # the grid read with the corners rolled by `rot` is the code upright
        out.append(CodeDetection(mid, lay, k, slot, np.roll(quads[q], -rot, axis=0)))
        read[q] = True
    # the budget of the second look: unread quads whose reading shows a code's frame (a
    # uniform black border, cells with contrast: `ok` at some shift), or that read
    # closer to one of our codes than chance; a ring's hull that takes in a pyramid's
    # edge reads 9-11 bits off and still holds a code the second look finds
    promising = ok.any(axis=1) | (best <= family.look_errors)
    return out, quads[~read & promising]


def rescue_codes(gray: np.ndarray, rejected: Sequence[np.ndarray] | np.ndarray | None,
                 found: Sequence[np.ndarray], family: CodeFamily, params: ArucoParams
                 ) -> tuple[list[CodeDetection], np.ndarray]:
    """The rescue stage for one family: :func:`candidate_quads`, then :func:`read_quads`.

    Returns:
        (the codes rescued; the (U, 4, 2) quads, px, still unread that deserve a second
        look).
    """
    quads = candidate_quads(gray, rejected, found, family, params)
    if len(quads) == 0:
        return [], _no_quads()
    return read_quads(gray, quads, family, params)
