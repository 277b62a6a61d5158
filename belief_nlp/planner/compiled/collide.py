"""Collision decisions of the compiled attempt, one (edge, hazard) pair at a time.

The same layers, with the same certificates and witnesses, as the numpy
checker (:mod:`..collision`, :mod:`..screen`, :mod:`..refine_scalar`), for
one transition x(s) = x0 + s (x1 - x0), P(s) = P0 + s W_e, s in [0, 1]:

1. face certificates with P(1) (:meth:`..screen.HazardScreen.clearances`);
2. witnesses: the mean segment meets the hazard (Liang-Barsky,
   :meth:`..screen.HazardScreen.segment_hits`), the end ellipse overlaps an
   obstacle (exact point distance, :meth:`..screen.HazardScreen.end_witness`);
3. walls in closed form (:meth:`..collision.CollisionChecker._walls_clear`);
4. obstacles: the sub-interval layers, depth first
   (:func:`..refine_scalar.refine_pairs`): the capsule certificate under
   P(s_b) and the middle witness, halving up to ``depth`` times.

An edge is clear only when every hazard has a certificate (1, 3 or 4); it is
blocked on a witness; otherwise it is left to the exact minimiser (the
caller runs :meth:`..collision.CollisionChecker._exact_rest`), so the
verdicts are those of the numpy checker up to rounding of the certificates,
which ``safety_margin`` covers there as here, and witnesses use
chi2' (1 - 1e-9). A covariance that is not positive definite gives NaN,
which passes no certificate and no witness: such pairs go to the exact check.

Data: ``F`` (H, Fm, 3) the faces (a0, a1, b) of the hazards (obstacles
first, then the walls, one face each), ``nf`` (H,) their counts; ``VE``
(m, k, 4) the obstacles' vertices and edge vectors (v0, v1, E0, E1), padded
as the checker's V, E.
"""

from __future__ import annotations

import math

from numba import njit

from .. import refine_scalar

CLEAR, BLOCKED, EXACT = 0, 1, 2


# The numpy checker's Python-float layers (:mod:`..refine_scalar`), compiled
# from the same source: the point distance, the capsule certificate and the
# factor (a polygon is the (k, 4) rows (v0, v1, E0, E1) of ``VE[j]``; NaN and
# inf where Python raises, and NaN fails every certificate and witness).
_jit = njit(cache=True, error_model="numpy")
factor = _jit(refine_scalar._factor)
point_dist2 = _jit(refine_scalar._point_dist2)
segment_clear = _jit(refine_scalar._segment_clear)


@njit(cache=True, error_model="numpy")
def refine_pair(xs0, xs1, dx0, dx1, p11, p12, p22, w11, w12, w22, VE, j, thr, thr_w, depth, stack) -> int:
    """One (edge, obstacle) pair by the sub-interval layers, depth first:
    BLOCKED on a middle witness, CLEAR when every sub-interval is certified,
    else EXACT. ``stack`` (>= depth + 2, 10) is scratch."""
    l11, l21, l22 = factor(p11 + w11, p12 + w12, p22 + w22)
    top = 0
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = 0.0, 1.0, xs0, xs1
    stack[0, 4], stack[0, 5], stack[0, 6], stack[0, 7] = xs0 + dx0, xs1 + dx1, l11, l21
    stack[0, 8], stack[0, 9] = l22, 0.0
    out = CLEAR
    while top >= 0:
        sa, sb, xa0, xa1, xb0, xb1 = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3], stack[top, 4], \
            stack[top, 5]
        b11, b21, b22, k = stack[top, 6], stack[top, 7], stack[top, 8], stack[top, 9]
        top -= 1
        if segment_clear(xa0, xa1, xb0, xb1, b11, b21, b22, VE[j], thr):
            continue
        sm = 0.5 * (sa + sb)
        xm0, xm1 = xs0 + sm * dx0, xs1 + sm * dx1
        m11, m21, m22 = factor(p11 + sm * w11, p12 + sm * w12, p22 + sm * w22)
        if point_dist2(xm0, xm1, m11, m21, m22, VE[j]) < thr_w:
            return BLOCKED
        if k >= depth:
            out = EXACT
            continue
        # second half pushed first: the first half is visited first
        top += 1
        stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3], stack[top, 4] = sm, sb, xm0, xm1, xb0
        stack[top, 5], stack[top, 6], stack[top, 7], stack[top, 8], stack[top, 9] = xb1, b11, b21, b22, k + 1
        top += 1
        stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3], stack[top, 4] = sa, sm, xa0, xa1, xm0
        stack[top, 5], stack[top, 6], stack[top, 7], stack[top, 8], stack[top, 9] = xm1, m11, m21, m22, k + 1
    return out


@njit(cache=True, error_model="numpy")
def _aPa(a0, a1, p11, p12, p22) -> float:
    return a0 * a0 * p11 + 2.0 * a0 * a1 * p12 + a1 * a1 * p22


@njit(cache=True, error_model="numpy")
def wall_clear(a0, a1, b, x00, x01, x10, x11, p11, p12, p22, w11, w12, w22, thr) -> bool:
    """The wall {a^T y <= b} exactly, in closed form: g(s) = (a^T x(s) - b)
    - sqrt(thr a^T P(s) a) >= 0 on [0, 1] (convex; its minimum is at an end
    or at the stationary point): :meth:`..collision.CollisionChecker._walls_clear`."""
    l0 = a0 * x00 + a1 * x01 - b
    dl = a0 * (x10 - x00) + a1 * (x11 - x01)
    q0 = thr * _aPa(a0, a1, p11, p12, p22)
    qw = thr * _aPa(a0, a1, w11, w12, w22)
    s_star = 0.0
    if dl > 0 and qw > 0:
        v = qw / (2.0 * dl)
        v = (v * v - q0) / qw
        if math.isfinite(v):
            s_star = min(max(v, 0.0), 1.0)
    g0 = l0 - math.sqrt(max(q0, 0.0))
    g1 = l0 + dl - math.sqrt(max(q0 + qw, 0.0))
    gs = l0 + s_star * dl - math.sqrt(max(q0 + s_star * qw, 0.0))
    return g0 >= 0.0 and g1 >= 0.0 and gs >= 0.0


@njit(cache=True, error_model="numpy")
def _segment_meets(F, nf, h, x00, x01, x10, x11) -> bool:
    """The mean segment meets hazard h (Liang-Barsky, boundary included)."""
    lower, upper = -math.inf, math.inf
    for f in range(nf[h]):
        a0, a1, b = F[h, f, 0], F[h, f, 1], F[h, f, 2]
        c0 = a0 * x00 + a1 * x01 - b
        c1 = a0 * x10 + a1 * x11 - b
        den = c0 - c1
        if den > 0:
            lower = max(lower, c0 / den)
        elif den < 0:
            upper = min(upper, c0 / den)
        elif c0 > 0:          # parallel and outside the face: no t
            return False
    return max(lower, 0.0) <= min(upper, 1.0)


@njit(cache=True, error_model="numpy")
def decide_edge(x00, x01, x10, x11, p11, p12, p22, w11, w12, w22, F, nf, n_obs, VE, thr, thr_w, depth,
                stack, pend):
    """(verdict, stage) of one transition against every hazard: verdict
    CLEAR, BLOCKED or EXACT (the exact minimiser must decide); stage 0 when
    the face certificates decided it, 1 the witnesses or walls, 2 the
    sub-interval layers. ``pend`` (H,) bool is scratch."""
    q11, q12, q22 = p11 + w11, p12 + w12, p22 + w22
    H = nf.shape[0]
    n_open = 0
    for h in range(H):
        ok = False
        for f in range(nf[h]):
            a0, a1, b = F[h, f, 0], F[h, f, 1], F[h, f, 2]
            c0 = a0 * x00 + a1 * x01 - b
            c1 = a0 * x10 + a1 * x11 - b
            s = min(c0, c1)
            if s > 0 and s * s >= thr * _aPa(a0, a1, q11, q12, q22):
                ok = True
                break
        pend[h] = not ok
        if not ok:
            n_open += 1
    if n_open == 0:
        return CLEAR, 0
    for h in range(H):
        if pend[h] and _segment_meets(F, nf, h, x00, x01, x10, x11):
            return BLOCKED, 1
    l11, l21, l22 = factor(q11, q12, q22)
    for h in range(n_obs):
        if pend[h] and point_dist2(x10, x11, l11, l21, l22, VE[h]) < thr_w:
            return BLOCKED, 1
    for h in range(n_obs, H):
        if pend[h] and not wall_clear(F[h, 0, 0], F[h, 0, 1], F[h, 0, 2], x00, x01, x10, x11, p11, p12, p22,
                                      w11, w12, w22, thr):
            return BLOCKED, 1
    out = CLEAR
    stage = 1
    for h in range(n_obs):
        if pend[h]:
            stage = 2
            v = refine_pair(x00, x01, x10 - x00, x11 - x01, p11, p12, p22, w11, w12, w22, VE, h, thr, thr_w,
                            depth, stack)
            if v == BLOCKED:
                return BLOCKED, 2
            if v == EXACT:
                out = EXACT
    return out, stage


@njit(cache=True, error_model="numpy")
def shrink_exponent(x0, x1, p11, p12, p22, F, nf, n_obs, VE, thr) -> int:
    """Smallest k >= 0 with E(x, P / 2^k) clear of every hazard, -1 when the
    mean is in a hazard or on its boundary:
    :meth:`..collision.CollisionChecker.shrink_exponent` (2-D)."""
    H = nf.shape[0]
    all_ok = True
    obs_ok = True
    for h in range(H):
        inside = True
        ok = False
        for f in range(nf[h]):
            a0, a1, b = F[h, f, 0], F[h, f, 1], F[h, f, 2]
            s = a0 * x0 + a1 * x1 - b
            if s > 0:
                inside = False
                if s * s >= thr * max(_aPa(a0, a1, p11, p12, p22), 0.0):
                    ok = True
        if inside:
            return -1
        if not ok:
            all_ok = False
            if h < n_obs:
                obs_ok = False
    if all_ok:
        return 0
    d2 = math.inf
    for h in range(n_obs, H):
        a0, a1, b = F[h, 0, 0], F[h, 0, 1], F[h, 0, 2]
        s = a0 * x0 + a1 * x1 - b
        d2 = min(d2, s * s / _aPa(a0, a1, p11, p12, p22))
    if not obs_ok:
        l11, l21, l22 = factor(p11, p12, p22)
        d2o = math.inf
        for h in range(n_obs):
            d = point_dist2(x0, x1, l11, l21, l22, VE[h])
            if d != d or d < d2o:
                d2o = d
        if not d2o > 0:
            return -1
        d2 = min(d2, d2o)
    if d2 >= thr:
        return 0
    return int(math.ceil(math.log2(thr / d2) + 1e-12))


@njit(cache=True, error_model="numpy")
def in_target(x0, x1, p11, p12, p22, T, thr) -> bool:
    """E(x, P) inside the target {A y <= b}, faces T (f, 3) = (a0, a1, b):
    :meth:`..collision.CollisionChecker.in_target`."""
    for f in range(T.shape[0]):
        if T[f, 2] - (T[f, 0] * x0 + T[f, 1] * x1) < 0:
            return False
    for f in range(T.shape[0]):
        a0, a1, b = T[f, 0], T[f, 1], T[f, 2]
        if not b - (a0 * x0 + a1 * x1) - math.sqrt(thr * max(_aPa(a0, a1, p11, p12, p22), 0.0)) >= 0.0:
            return False
    return True


@njit(cache=True, error_model="numpy")
def decide_batch(x0, P0, x1, We, F, nf, n_obs, VE, thr, thr_w, depth, stack, pend, status) -> None:
    """:func:`decide_edge` on every row of a batch (x0 (n, 2), P0 (n, 2, 2)
    symmetric, x1 (n, 2), We (n, 2, 2)); verdicts into ``status`` (n,)."""
    for i in range(x0.shape[0]):
        status[i] = decide_edge(x0[i, 0], x0[i, 1], x1[i, 0], x1[i, 1], P0[i, 0, 0], P0[i, 0, 1], P0[i, 1, 1],
                                We[i, 0, 0], We[i, 0, 1], We[i, 1, 1], F, nf, n_obs, VE, thr, thr_w, depth, stack,
                                pend)[0]
