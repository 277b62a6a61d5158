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
from .bounds import certificate_lower, decide
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

    ``dist2`` is the best value found, an upper bound on the minimum;
    ``lower`` the rigorous lower bound (Theorem-1 certificate value of the
    minimiser's lam, :mod:`.bounds`); ``decided`` says whether the bounds
    decide the pair against ``threshold`` (without one: whether the
    minimisation finished before ``max_iter``). Decide acceptance on
    ``lower``, never on ``dist2``.
    """
    return _minimum(x_prev, P_prev, x_next, W, _as_set(polytopes), tol, max_iter, threshold, True, want_lam,
                    _generic)


def _minimum(x_prev, P_prev, x_next, W, ps: PolytopeSet, tol: float, max_iter: int, threshold: float | None,
             want_s: bool, want_lam: bool, generic: bool = False, want_lower: bool = True) -> TransitionMinimum:
    """Batch the transitions (``W`` shared or per transition) and run the
    planar path, or the generic one (any dimension, or 2-D on request);
    then the rigorous lower bound from the certificates (:mod:`.bounds`)
    and the decisions."""
    x0, P0, _ = _batch(x_prev, P_prev)
    x1 = np.atleast_2d(np.asarray(x_next, float))
    W = np.asarray(W, float)
    W = np.broadcast_to(W, P0.shape) if W.ndim == 2 else W
    need_lam = want_lam or want_lower
    if ps.planar is not None and not generic:
        tm = _planar_transitions(ps, x0, P0, x1, W, tol, max_iter, threshold, want_s, need_lam)
    else:
        tm = _generic_transitions(ps, x0, P0, x1, W, tol, max_iter, need_lam, threshold)
    if not want_lower:
        return tm
    # both bounds are valid; min keeps lower <= upper where rounding puts the
    # upper bound (computed for a real point) a hair below the truth (needles)
    tm.lower = np.minimum(certificate_lower(ps.A, ps.b, x0, P0, x1, W, tm.lam), tm.dist2)
    if threshold is None:
        tm.decided = ~tm.limited
    else:
        tm.decided = decide(tm.lower, tm.dist2, threshold)[1]
        if not tm.decided.all():
            _refine(tm, x0, P0, x1, W, ps, tol, max_iter, threshold, want_s, generic)
    if not want_lam:
        tm.lam = None
    return tm


def _refine(tm: TransitionMinimum, x0, P0, x1, W, ps: PolytopeSet, tol: float, max_iter: int, threshold: float,
            want_s: bool, generic: bool) -> None:
    """Minimise the pairs a threshold left undecided again, in full.

    The threshold shortcut skips curves whose tangent bound already clears
    the threshold, so the certificate of the feature that attains the best
    value seen may not be the minimiser's (its value can then fall below
    the threshold although the pair is clear). The full minimisation finds
    the minimiser and its certificate; both bounds stay valid, so each pair
    keeps the better of the two. Rare: the planner's edges almost never
    get here."""
    rows = np.flatnonzero(~tm.decided.all(axis=1))
    full = _minimum(x0[rows], P0[rows], x1[rows], W[rows], ps, tol, max_iter, None, want_s, True, generic)
    und = ~tm.decided[rows]
    r, j = rows[np.nonzero(und)[0]], np.nonzero(und)[1]
    better = full.lower[und] > tm.lower[r, j]
    tm.dist2[r, j] = np.minimum(tm.dist2[r, j], full.dist2[und])
    tm.lower[r, j] = np.minimum(np.maximum(tm.lower[r, j], full.lower[und]), tm.dist2[r, j])
    if tm.lam is not None:
        tm.lam[r[better], j[better]] = full.lam[und][better]
    if want_s and tm.s is not None:
        tm.s[r, j] = full.s[und]
    tm.limited[r, j] = full.limited[und]
    tm.decided = decide(tm.lower, tm.dist2, threshold)[1]


@_quiet
def _min_dist2(x_prev, P_prev, x_next, W, polytopes, threshold: float | None) -> np.ndarray:
    """min_s dist2 (n, m) without minimisers or certificates (the fast
    value-only path); with ``threshold``, exact only where that decides
    nothing. An upper bound: never the basis of an acceptance."""
    return _minimum(x_prev, P_prev, x_next, W, _as_set(polytopes), 1e-10, 60, threshold, False, False,
                    want_lower=False).dist2


@_quiet
def transition_bounds(x_prev, P_prev, x_next, W, polytopes, threshold: float | None = None, *,
                      tol: float = 1e-10, max_iter: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper), each (n, m): the minimum over s in [0, 1] of dist2
    lies in [lower, upper] for every transition/polytope pair.

    ``lower`` is the Theorem-1 certificate value min(f_0(lam), f_1(lam)) of
    the minimiser's lam, less its rounding bound (rigorous whatever the
    minimiser did, see :mod:`.bounds`); ``upper`` the best value found (a
    real point at a real s). With ``threshold`` each pair stops as soon as
    the bounds decide it: lower >= threshold (clear) or upper < threshold
    (collision); a pair left with lower < threshold <= upper (the iteration
    limit, or a minimum within rounding of the threshold) is undecided.
    """
    tm = _minimum(x_prev, P_prev, x_next, W, _as_set(polytopes), tol, max_iter, threshold, False, False)
    return tm.lower, tm.dist2


def transition_clearances(x_prev, P_prev, x_next, W, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`transition_clearance`: n transitions vs m polytopes -> (n, m).

    ``x_prev``, ``x_next`` (n, d); ``P_prev`` (n, d, d); ``W`` (d, d) shared
    or (n, d, d) per transition. The minimum found (an upper bound, tight to
    ~1e-10 relative); :func:`transition_bounds` gives the rigorous lower
    bound next to it.
    """
    return _min_dist2(x_prev, P_prev, x_next, W, polytopes, None) - chi2


def transitions_clear(x_prev, P_prev, x_next, W, polytopes, chi2: float, margin: float = 0.0, *,
                      max_iter: int = 60) -> np.ndarray:
    """Boolean (n, m): is each transition *proven* clear of each polytope,
    dist2 >= chi2 + margin for all s? True only when the rigorous lower
    bound (:func:`transition_bounds`) clears the threshold: an undecided
    pair (iteration limit, or a minimum within rounding of the threshold)
    is False. Stops each pair as soon as it is decided, which is what a
    planner needs."""
    thr = chi2 + margin
    lower, _ = transition_bounds(x_prev, P_prev, x_next, W, polytopes, thr, max_iter=max_iter)
    return lower >= thr


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
