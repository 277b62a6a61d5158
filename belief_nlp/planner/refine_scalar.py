"""The 2-D sub-interval layers of the collision checker for a few pairs, in Python floats.

:meth:`.collision.CollisionChecker._refine2` decides the (edge, obstacle)
pairs the screen left open, breadth first over sub-intervals, in numpy. A
round there is about forty numpy calls whatever the number of rows, and the
planner's rounds are small (median four rows), so a round costs about
100-200 us while one sub-interval in Python floats costs about 10 us.
:func:`refine_pairs` is the same computation for one pair at a time, depth
first, in plain floats:

* the same values: every quantity of :func:`.collision._sweep_dist2` is an
  elementwise +, -, *, /, sqrt, min or max (no matrix product, no
  transcendental function), which IEEE 754 rounds the same in Python as in
  numpy, and the formulas below keep numpy's order of operations; the
  minima propagate NaN as ``np.minimum`` does. A division by zero or the
  root of a negative number (a covariance that is not positive definite),
  where numpy would give inf/NaN and Python raises, is reported to the
  caller as ``None`` so that it runs the numpy layers instead;
* the same verdicts: an edge is blocked iff some sub-interval of one of its
  pairs (up to ``depth`` halvings, not below a cleared one) has a middle
  witness, and goes to the exact check iff it is not blocked and some
  sub-interval at the last depth is neither cleared nor witnessed. That set
  does not depend on the order in which the sub-intervals are visited, so
  depth first per pair decides what the breadth-first rounds decide (both
  stop working on an edge once it is blocked, which changes no verdict).
  The segment certificate ``seg >= thr`` is the conjunction of its three
  parts (NaN fails each), so they are evaluated only until one fails.
"""

from __future__ import annotations

import math

__all__ = ["refine_pairs"]


def _point_dist2(x0: float, x1: float, l11: float, l21: float, l22: float, poly) -> float:
    """Squared Mahalanobis distance from (x0, x1) to the boundary of ``poly``
    (tuples (v0, v1, E0, E1) per vertex, padded as the checker's V, E) under
    the factor (l11, l21, l22): :func:`.collision._boundary_parts`, one row."""
    best = math.inf
    for v0, v1, E0, E1 in poly:
        w0 = (v0 - x0) / l11
        w1 = ((v1 - x1) - l21 * w0) / l22
        e0 = E0 / l11
        e1 = (E1 - l21 * e0) / l22
        ee = e0 * e0 + e1 * e1 + 1e-300
        t = -(w0 * e0 + w1 * e1) / ee
        # np.minimum(np.maximum(t, 0), 1), NaN kept
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        q0 = w0 + t * e0
        q1 = w1 + t * e1
        d = q0 * q0 + q1 * q1
        if d < best or d != d:
            best = d
            if d != d:
                return d
    return best


def _factor(p00: float, p01: float, p11: float) -> tuple[float, float, float]:
    """:func:`.collision._chol2`, one matrix (ValueError / ZeroDivisionError
    where numpy would give NaN / inf)."""
    l11 = math.sqrt(p00)
    l21 = p01 / l11
    r = p11 - l21 * l21
    return l11, l21, math.sqrt(r if r >= 0.0 or r != r else 0.0)


def _segment_clear(xa0, xa1, xb0, xb1, l11, l21, l22, poly, thr) -> bool:
    """``seg >= thr`` of :func:`.collision._sweep_dist2`: the segment [xa, xb]
    whitened by the factor stays sqrt(thr) away from the polygon. That is
    every term of its minimum (the two ends' distances, as
    :func:`_point_dist2`, and the polygon's vertices against the segment)
    being >= thr, so one pass over the vertices stops at the first term that
    is not (NaN included)."""
    u0 = (xb0 - xa0) / l11
    u1 = ((xb1 - xa1) - l21 * u0) / l22
    uu = u0 * u0 + u1 * u1 + 1e-300
    ends = ((xb0, xb1), (xa0, xa1))
    for v0, v1, E0, E1 in poly:
        e0 = E0 / l11
        e1 = (E1 - l21 * e0) / l22
        ee = e0 * e0 + e1 * e1 + 1e-300
        # the ends: the nearest point of the polygon's edge from this vertex
        for y0, y1 in ends:
            w0 = (v0 - y0) / l11
            w1 = ((v1 - y1) - l21 * w0) / l22
            t = -(w0 * e0 + w1 * e1) / ee
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            q0 = w0 + t * e0
            q1 = w1 + t * e1
            if not q0 * q0 + q1 * q1 >= thr:
                return False
        # the vertex against the segment (w: the polygon whitened about xa, the last end)
        t = (w0 * u0 + w1 * u1) / uu
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        q0 = w0 - t * u0
        q1 = w1 - t * u1
        if not q0 * q0 + q1 * q1 >= thr:
            return False
    return True


def refine_pairs(pairs: list, polys: list, thr: float, thr_witness: float,
                 depth: int) -> tuple[set, set] | None:
    """Decide open (edge, obstacle) pairs by the sub-interval layers.

    ``pairs``: per pair (edge, obstacle, (xs0, xs1), (dx0, dx1), (ps00,
    ps01, ps10, ps11), (w00, w01, w10, w11)): the edge's start mean, its
    step x1 - x0, its start covariance P0 and noise W_e; ``polys[obstacle]``
    the polygon as :func:`_point_dist2` reads it. Returns (blocked, open):
    the edges with a witness, and the other edges with a pair still open
    after ``depth`` halvings; None when a covariance is not positive
    definite (the caller then uses the numpy layers).
    """
    blocked: set = set()
    left: set = set()
    try:
        for e, j, (xs0, xs1), (dx0, dx1), (ps00, ps01, _, ps11), (w00, w01, _, w11) in pairs:
            if e in blocked:
                continue
            poly = polys[j]
            # (sa, sb, xa, xb, factor of Pb, depth), Pb = P(sb) the largest covariance on
            # [sa, sb] (a child's Pb is its parent's or the parent's middle one, so
            # its factor is carried along, not computed again)
            stack = [(0.0, 1.0, xs0, xs1, xs0 + dx0, xs1 + dx1, _factor(ps00 + w00, ps01 + w01, ps11 + w11), 0)]
            while stack:
                sa, sb, xa0, xa1, xb0, xb1, fb, k = stack.pop()
                if _segment_clear(xa0, xa1, xb0, xb1, *fb, poly, thr):
                    continue
                sm = 0.5 * (sa + sb)
                xm0, xm1 = xs0 + sm * dx0, xs1 + sm * dx1
                fm = _factor(ps00 + sm * w00, ps01 + sm * w01, ps11 + sm * w11)
                if _point_dist2(xm0, xm1, *fm, poly) < thr_witness:
                    blocked.add(e)
                    left.discard(e)
                    break
                if k == depth:
                    left.add(e)
                    continue
                # second half pushed first: the first half is visited first
                stack.append((sm, sb, xm0, xm1, xb0, xb1, fb, k + 1))
                stack.append((sa, sm, xa0, xa1, xm0, xm1, fm, k + 1))
    except (ValueError, ZeroDivisionError):
        return None
    return blocked, left
