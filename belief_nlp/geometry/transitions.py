"""Exact collision checks of transitions (paper Definition 3, Theorem 1).

A transition x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W,
s in [0, 1] (errata 5) is clear of a polytope iff min over s of
dist2(x(s), P(s)) >= chi2. dist2(s) is convex and C1 in s (Theorem 1's
minimax argument), so everything here computes that minimum exactly (a 1-D
convex minimisation to ~1e-10, never sampling s): 2-D polygons by the
planar path (:mod:`.planar`), other dimensions by the generic one
(:mod:`.generic`). The minimiser comes with Theorem 1's common certificate:
one lam >= 0 valid at both ends of the transition.
"""

from __future__ import annotations

import numpy as np

from ._numeric import _batch, _quiet
from .generic import _generic_transitions
from .minimise import TransitionMinimum
from .planar import _planar_transitions
from .polytopes import PolytopeSet, _as_set


@_quiet
def transition_minimiser(x_prev, P_prev, x_next, W, polytopes, tol: float = 1e-10,
                         max_iter: int = 60, want_lam: bool = False,
                         threshold: float | None = None, _generic: bool = False) -> TransitionMinimum:
    """Minimise dist2(x(s), P(s)) over s in [0, 1] for every transition/polytope pair.

    x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W. The function
    is convex in s, so the tangents at the ends of a bracket give a lower
    bound LB; a pair is converged when best - LB <= tol * (1 + best).
    2-D polygons use the planar path (closed-form edges, see
    :func:`.planar._planar_transitions`), other dimensions a bracketed
    iteration on dist2(s) itself (:func:`.minimise._minimise_brackets`).

    With ``threshold`` set, a pair also stops as soon as it is decided
    against it (some g(s) < threshold, or LB >= threshold); ``dist2`` is
    then exact only for the pairs that did not stop early, but always on the
    correct side of ``threshold``.
    """
    return _minimum(x_prev, P_prev, x_next, W, _as_set(polytopes), tol, max_iter, threshold, True, want_lam,
                    _generic)


def _minimum(x_prev, P_prev, x_next, W, ps: PolytopeSet, tol: float, max_iter: int, threshold: float | None,
             want_s: bool, want_lam: bool, generic: bool = False) -> TransitionMinimum:
    """Batch the transitions (``W`` shared or per transition) and run the
    planar path, or the generic one (any dimension, or 2-D on request)."""
    x0, P0, _ = _batch(x_prev, P_prev)
    x1 = np.atleast_2d(np.asarray(x_next, float))
    W = np.asarray(W, float)
    W = np.broadcast_to(W, P0.shape) if W.ndim == 2 else W
    if ps.planar is not None and not generic:
        return _planar_transitions(ps, x0, P0, x1, W, tol, max_iter, threshold, want_s, want_lam)
    return _generic_transitions(ps, x0, P0, x1, W, tol, max_iter, want_lam, threshold)


@_quiet
def _min_dist2(x_prev, P_prev, x_next, W, polytopes, threshold: float | None) -> np.ndarray:
    """min_s dist2 (n, m) without minimisers or certificates (the planner's
    hot path); with ``threshold``, exact only where that decides nothing."""
    return _minimum(x_prev, P_prev, x_next, W, _as_set(polytopes), 1e-10, 60, threshold, False, False).dist2


def transition_clearances(x_prev, P_prev, x_next, W, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`transition_clearance`: n transitions vs m polytopes -> (n, m).

    ``x_prev``, ``x_next`` (n, d); ``P_prev`` (n, d, d); ``W`` (d, d) shared
    or (n, d, d) per transition.
    """
    return _min_dist2(x_prev, P_prev, x_next, W, polytopes, None) - chi2


def transitions_clear(x_prev, P_prev, x_next, W, polytopes, chi2: float, margin: float = 0.0) -> np.ndarray:
    """Boolean (n, m): is each transition clear of each polytope with
    dist2 >= chi2 + margin for all s? Exact decision (same maths as
    :func:`transition_clearances`) but stops each pair as soon as it is decided,
    which is what a planner needs."""
    thr = chi2 + margin
    return _min_dist2(x_prev, P_prev, x_next, W, polytopes, thr) >= thr


def transition_clearance(x_prev, P_prev, x_next, W, A, b, chi2: float):
    """min over s in [0, 1] of ellipse_clearance(x(s), P(s), A, b, chi2).

    x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W (paper Definition
    3). ``>= 0`` iff the whole transition is collision-free (Theorem 1 with the
    corrected eq. tran_col_2, errata 5). Exact (a 1-D convex minimisation),
    not sampled. Float for a single transition, (n,) array when batched.
    """
    x0, P0, single = _batch(x_prev, P_prev)
    out = transition_clearances(x0, P0, np.atleast_2d(np.asarray(x_next, float)), W, _as_set(A, b), chi2)[:, 0]
    return float(out[0]) if single else out


def transition_certificate(x_prev, P_prev, x_next, W, A, b) -> tuple[np.ndarray, float]:
    """A common lam >= 0 for both ends of a transition (Theorem 1) and its value.

    Returns ``(lam, value)`` where value = min(f_0(lam), f_1(lam)) with
    f_s(lam) = -lam^T A P(s) A^T lam + 2 lam^T (A x(s) - b). The transition is
    clear iff value >= chi2 is achievable; this lam attains the optimum
    min_s dist2(s) up to solver tolerance.
    """
    ps = _as_set(A, b)
    tm = transition_minimiser(x_prev, P_prev, x_next, W, ps, want_lam=True)
    f = ps.n_faces[0]
    lam = tm.lam[0, 0, :f]
    A = ps.A[0, :f]
    b = ps.b[0, :f]
    x0 = np.asarray(x_prev, float)
    x1 = np.asarray(x_next, float)
    P0 = np.asarray(P_prev, float)
    P1 = P0 + np.asarray(W, float)
    v = lam @ A
    f0 = -v @ P0 @ v + 2 * lam @ (A @ x0 - b)
    f1 = -v @ P1 @ v + 2 * lam @ (A @ x1 - b)
    return lam, float(min(f0, f1))
