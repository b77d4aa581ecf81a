"""Which planar solution each dot brick reports, and a symmetric layout's half-turn.

The planar ambiguity is decided by the one rule both detectors use
(:func:`drovisio.pose.decide_flips`: gravity, the previous frame, the image, "close"); bricks
still undecided then use the up of the decided ones (:func:`drovisio.detect.base.decided_up`)
and are otherwise flagged ambiguous with the better fit reported. A symmetric layout's yaw
is put in one canonical half-turn, or the previous frame's in a stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drovisio.detect.base import decided_up
from drovisio.detect.dots.batch import Context, DotBatch
from drovisio.detect.dots.poses import chi2
from drovisio.detect.dots.stream import PreviousBrick, previous_flip, previous_rotations
from drovisio.pose import HALF_TURN, canonical_half_turn, decide_flips

__all__ = ["Decision", "decide"]


@dataclass(frozen=True)
class Decision:
    """The reported solution of each accepted brick (n of them)."""

    rows: np.ndarray
    """(n,) the bricks in the batch."""
    R2: np.ndarray
    """(n, 2, 3, 3) both solutions, camera_from_brick (as solved, before any half-turn)."""
    t2: np.ndarray
    """(n, 2, 3) their translations, metres."""
    choose: np.ndarray
    """(n,) the solution reported (0 or 1)."""
    ambiguous: np.ndarray
    """(n,) bool: the rule could not decide (the better fit is reported)."""
    R: np.ndarray
    """(n, 3, 3) the reported rotation (half-turned where ``flip``)."""
    t: np.ndarray
    """(n, 3) the reported translation, metres."""
    symmetric: np.ndarray
    """(n,) bool: the layout is symmetric under a half-turn."""
    flip: np.ndarray
    """(n,) bool: the reported rotation is the solution's half-turn."""


def decide(ctx: Context, bt: DotBatch, rows: np.ndarray, gravity: np.ndarray | None,
           previous: list[PreviousBrick] | None) -> Decision:
    """The planar ambiguity of the accepted bricks ``rows``, then the symmetric half-turn
    (``previous``: the previous frame's bricks in a stream, else None)."""
    B = rows.size
    ar = np.arange(B)
    R2, t2 = bt.R[rows], bt.t[rows]
    choose, ambiguous = _choose(ctx, bt, rows, R2, t2, gravity, previous)
    Rc, tc = R2[ar, choose], t2[ar, choose]
    sym, flip = _half_turns(bt, rows, Rc, tc, previous)
    if sym.any():
        Rc = np.where(flip[:, None, None], Rc * HALF_TURN, Rc)
    return Decision(rows=rows, R2=R2, t2=t2, choose=choose, ambiguous=ambiguous, R=Rc, t=tc,
                    symmetric=sym, flip=flip)


def _choose(ctx: Context, bt: DotBatch, rows: np.ndarray, R2: np.ndarray, t2: np.ndarray,
            gravity: np.ndarray | None, previous: list[PreviousBrick] | None
            ) -> tuple[np.ndarray, np.ndarray]:
    """(solution index (n,), ambiguous (n,)): the one rule, then the bricks still undecided
    with the up of the decided ones; undecided bricks get their better fit."""
    rule = ctx.config.ambiguity
    ar = np.arange(rows.size)
    c2, dof = chi2(ctx, bt, rows)
    prev = previous_rotations(bt, rows, R2, t2, previous)
    choose, why = decide_flips(R2, c2, dof, gravity=gravity, previous=prev, rule=rule)
    undecided = choose < 0
    up = decided_up(R2[ar, np.maximum(choose, 0)], why, undecided)
    if up is not None:
        u = np.flatnonzero(undecided)
        choose[u], _ = decide_flips(R2[u], c2[u], dof[u], gravity=gravity,
                                    reference_up=up, rule=rule,
                                    previous=None if prev is None else [prev[k] for k in u])
    ambiguous = choose < 0
    return np.where(ambiguous, 0, choose), ambiguous


def _half_turns(bt: DotBatch, rows: np.ndarray, Rc: np.ndarray, tc: np.ndarray,
                previous: list[PreviousBrick] | None) -> tuple[np.ndarray, np.ndarray]:
    """(symmetric (n,), flip (n,)): symmetric layouts in one canonical half-turn (the
    previous frame's, in a stream)."""
    B = rows.size
    if bt.single is not None:
        sym = np.full(B, bt.single.sym_perm is not None)
    else:
        sym = np.array([bt.models[r].sym_perm is not None for r in rows.tolist()])
    flip = np.zeros(B, bool)
    if not sym.any():
        return sym, flip
    flip = sym & canonical_half_turn(Rc)
    prev = previous if previous is not None else []
    if prev:
        for k in np.flatnonzero(sym).tolist():
            f = previous_flip(bt.models[rows[k]], Rc[k], tc[k], prev)
            if f is not None:
                flip[k] = f
    return sym, flip
