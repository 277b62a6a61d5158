"""Minimisation over s of a convex C1 function on [0, 1], vectorised.

Along a transition (paper Definition 3) dist2(s) is convex and C1 in s
(Theorem 1's minimax argument), so its minimum over [0, 1] is found exactly
by bracketing: the tangents at the ends of a bracket give a rigorous lower
bound, and the iteration stops when the best value is within a relative
``tol`` of it -- s is never sampled. Both the planar and the generic paths
use :func:`_minimise_brackets`, and both return a :class:`TransitionMinimum`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class TransitionMinimum:
    """Result of :func:`transition_minimiser` for n transitions x m polytopes.

    ``dist2`` is the best value found, an upper bound on the minimum (a real
    point of the polytope at a real s); ``lower`` is a rigorous lower bound
    (the Theorem-1 certificate value, see :mod:`.bounds`), so the true
    minimum lies in [lower, dist2]. ``decided``: with a threshold, the bounds
    put the pair on one side of it (lower >= threshold: clear, dist2 <
    threshold: collision); without one, the pair's minimisation finished
    (it did not stop at the iteration limit).
    """

    dist2: np.ndarray        # (n, m) min over s in [0, 1] of the squared distance (an upper bound)
    s: np.ndarray | None     # (n, m) minimiser (None only on the planner's value-only path)
    lam: np.ndarray | None   # (n, m, F) common certificate (Theorem 1), padded faces; None unless asked
    iterations: int          # bracketing rounds (planar: 0 when closed forms and Newton guesses settle all)
    lower: np.ndarray | None = None     # (n, m) rigorous lower bound on the minimum (None on value-only paths)
    decided: np.ndarray | None = None   # (n, m) bool, see above
    limited: np.ndarray | None = None   # (n, m) bool: stopped by the iteration limit, not by its bounds


def _rational_step(d: np.ndarray, h: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Offset to the minimiser of m(s) = A/(s - s_p) + B + C s fitted to g', g''.

    dist2 along a transition behaves like this model: an ellipse vertex term
    |r(s)|^2 / (p + s w) has exactly this form with the pole s_p = -p/w where
    P(s) turns singular. Plain Newton (the tau -> inf limit, to which this
    reduces) crawls on such functions when P_prev is tiny -- steps grow by
    x1.5 per iteration near the pole -- while this step is exact for them.
    ``tau = s - s_p > 0``; NaN when the model has no minimum (caller falls back).
    Written as -2 d / (h sq (1 + sq)) to stay accurate for tau -> inf.
    """
    sq = np.sqrt(1.0 + 2.0 * d / (h * tau))
    return -2.0 * d / (h * sq * (1.0 + sq))


def _minimise_brackets(ends: np.ndarray, pole: np.ndarray, payload: np.ndarray, evaluate: Callable,
                       tol: float, max_iter: int, stop: Callable | None = None,
                       aux: np.ndarray | None = None) -> tuple[int, np.ndarray, np.ndarray, np.ndarray | None]:
    """Vectorised safeguarded minimisation of k convex C1 functions on brackets.

    ``ends`` (4, 2, k): rows s, g, g', g'' at the bracket ends (lo, hi), with
    g'(lo) < 0 < g'(hi), so the minimiser is inside and the best value seen
    is always min(g(lo), g(hi)) (convexity). Each round proposes two points
    -- the rational step (:func:`_rational_step`) from each end, falling back
    to the tangent intersection / midpoint when a step leaves the bracket --
    evaluated together in one batched call (for small batches the cost is
    the number of numpy calls, not their size), and keeps the sub-bracket
    where g' changes sign. The end tangents give a rigorous lower bound LB,
    which is the stopping test: best - LB <= tol (1 + |best|).

    ``evaluate(s (2, k'), payload (..., k'))`` returns ((4, 2, k') like
    ``ends``, aux at the points (2, r, k') or None); ``payload`` is the
    per-entry data, compressed here as entries retire. ``stop(pos, best, lb)``
    may retire entries early (threshold decisions, pruning); ``pos`` are the
    original entry indices. ``aux`` (2, r, k) rides along with the ends.
    Returns (rounds, final ends, final LB, final aux, limited), in the
    original order; ``limited`` marks the entries the iteration limit
    stopped (neither converged nor retired by ``stop``).
    """
    k = ends.shape[2]
    out_ends = np.empty_like(ends)
    out_lb = np.empty(k)
    out_limited = np.zeros(k, dtype=bool)
    out_aux = None if aux is None else np.empty_like(aux)
    pos = np.arange(k)
    it = 0
    while True:
        s, g, d = ends[0], ends[1], ends[2]
        t = np.minimum(np.maximum((g[1] - g[0] + d[0] * s[0] - d[1] * s[1]) / (d[0] - d[1]), s[0]), s[1])
        lb = g[0] + d[0] * (t - s[0])
        best = np.minimum(g[0], g[1])
        done = (best - lb <= tol * (1.0 + np.abs(best))) | (s[1] - s[0] <= 1e-15)
        if stop is not None:
            done |= stop(pos, best, lb)
        if it >= max_iter:
            out_limited[pos[~done]] = True
            done[:] = True
        if done.any():
            p = pos[done]
            out_ends[:, :, p] = ends[:, :, done]
            out_lb[p] = lb[done]
            if aux is not None:
                out_aux[:, :, p] = aux[:, :, done]
            keep = ~done
            if not keep.any():
                return it, out_ends, out_lb, out_aux, out_limited
            pos, ends, pole, t = pos[keep], ends[:, :, keep], pole[keep], t[keep]
            payload = payload[..., keep]
            if aux is not None:
                aux = aux[:, :, keep]
            s = ends[0]
        it += 1
        cand = s + _rational_step(ends[2], ends[3], s - pole)
        fallback = np.stack([t, 0.5 * (s[0] + s[1])])
        cand = np.sort(np.where((cand > s[0]) & (cand < s[1]), cand, fallback), axis=0)
        pts, paux = evaluate(cand, payload)
        left = pts[2, 0] >= 0                     # minimiser in [lo, p0]
        mid = ~left & (pts[2, 1] >= 0)            # in [p0, p1]; else in [p1, hi]
        lo_new = np.where(left, ends[:, 0], np.where(mid, pts[:, 0], pts[:, 1]))
        hi_new = np.where(left, pts[:, 0], np.where(mid, pts[:, 1], ends[:, 1]))
        ends = np.stack([lo_new, hi_new], axis=1)
        if aux is not None:
            aux = np.stack([np.where(left, aux[0], np.where(mid, paux[0], paux[1])),
                            np.where(left, paux[0], np.where(mid, paux[1], aux[1]))])


def _decided(threshold: float | None) -> Callable | None:
    """Early stop for :func:`_minimise_brackets` in threshold mode: an entry
    is decided once some value is below the threshold or its lower bound is
    above it."""
    if threshold is None:
        return None
    return lambda pos, best, lb: (best < threshold) | (lb >= threshold)


def _left_pole(P0: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Largest root s_p < 0 of det(P0 + s W) per transition (-inf if none).

    It is where P(s) of Definition 3 would turn singular, the pole that makes
    dist2(s) steep near s = 0 when P_prev is small; see :func:`_rational_step`.
    """
    try:
        L = np.linalg.cholesky(P0)
        Li = np.linalg.inv(L)
        lam = np.linalg.eigvalsh(Li @ W @ np.swapaxes(Li, -1, -2))[..., -1]
    except np.linalg.LinAlgError:
        return np.full(P0.shape[0], -np.inf)
    with np.errstate(divide="ignore"):
        return np.where(lam > 0, -1.0 / lam, -np.inf)


def _mix_certificates(d_lo: np.ndarray, d_hi: np.ndarray, lam_lo: np.ndarray, lam_hi: np.ndarray) -> np.ndarray:
    """theta lam_lo + (1 - theta) lam_hi for an only-bracketed minimiser s*.

    ``d_lo <= 0 <= d_hi`` are the slopes at the bracket's ends, ``lam_lo``,
    ``lam_hi`` (..., k) the certificates there. The weight theta that cancels
    the slopes makes the mixture's value flat in s (Theorem 1's common
    lambda); that value is then >= the tangent lower bound.
    """
    theta = np.clip(np.nan_to_num(d_hi / (d_hi - d_lo)), 0.0, 1.0)
    return theta * lam_lo + (1 - theta) * lam_hi
