"""2x2 kernels of the compiled attempt: factors, eigenvalues, edge information, steering.

Each function is the scalar form of a numpy kernel of the planner (named in
its docstring), with the same formulas and order of operations; results
agree to rounding (numba's libm ``log``/``expm1`` may differ from numpy's by
an ulp), which the compiled backend does not need to match bit for bit.
Symmetric matrices are passed as their entries (p11, p12, p22).
"""

from __future__ import annotations

import math

from numba import njit

from ..metrics import LOSSLESS_RTOL

# metric codes of the compiled backend
ENTROPY, HELLINGER = 0, 1
LOSSLESS_MIN = 1.0 + LOSSLESS_RTOL


@njit(cache=True, error_model="numpy")
def chol2(a: float, b: float, c: float):
    """(l11, l21, l22, ok) of [[a, b], [b, c]]: :func:`..kernels.chol2`
    (ok False where that raises: not positive definite)."""
    if not a > 0:
        return 0.0, 0.0, 0.0, False
    l11 = math.sqrt(a)
    l21 = b / l11
    r = c - l21 * l21
    if not r > 0:
        return 0.0, 0.0, 0.0, False
    return l11, l21, math.sqrt(r), True


@njit(cache=True, error_model="numpy")
def eig_pair(m11: float, m12: float, m22: float):
    """(smaller, larger) eigenvalue of a symmetric 2x2: :func:`..kernels._eig2_pair`."""
    half_tr = 0.5 * (m11 + m22)
    m12sq = m12 * m12
    h = 0.5 * (m11 - m22)
    disc = math.sqrt(h * h + m12sq)
    big = half_tr + disc
    det = m11 * m22 - m12sq
    if big > 0:
        return det / big, big
    return half_tr - disc, big


@njit(cache=True, error_model="numpy")
def congruence_pair(s11: float, s12: float, s22: float, t11: float, t21: float, t22: float):
    """Eigenvalues of T S T^T, T lower triangular: :func:`..kernels.lower_congruence_eig2`."""
    m11 = t11 * t11 * s11
    m12 = t11 * t21 * s11 + t11 * t22 * s12
    m22 = t21 * t21 * s11 + 2.0 * t21 * t22 * s12
    m22 += t22 * t22 * s22
    return eig_pair(m11, m12, m22)


@njit(cache=True, error_model="numpy")
def info_pair(small: float, big: float, floor: float, metric: int) -> float:
    """The metric value from the generalised eigenvalues floored at ``floor``:
    :meth:`..metrics.EdgeMetric._from_pair`."""
    a = max(small, floor)
    b = max(big, floor)
    if metric == ENTROPY:
        return 0.5 * (math.log(a) + math.log(b))
    a = max(a, 1e-300)
    b = max(b, 1e-300)
    log_bc = (0.25 * math.log(a) - 0.5 * math.log(0.5 * (1.0 + a))) + (0.25 * math.log(b)
                                                                       - 0.5 * math.log(0.5 * (1.0 + b)))
    return math.sqrt(max(-math.expm1(log_bc), 0.0))


@njit(cache=True, error_model="numpy")
def inv_factor(l11: float, l21: float, l22: float):
    """Entries (t11, t21, t22) of L^-1: :func:`..kernels.chol_pair2`."""
    return 1.0 / l11, -l21 / (l11 * l22), 1.0 / l22


@njit(cache=True, error_model="numpy")
def eigh2(a: float, b: float, c: float):
    """(larger, smaller, cos, sin) of [[a, b], [b, c]]: :func:`..kernels.eigh2`."""
    th = 0.5 * math.atan2(2.0 * b, a - c)
    co, si = math.cos(th), math.sin(th)
    big = a * co * co + 2.0 * b * co * si + c * si * si
    if big > 0:
        small = (a * c - b * b) / big
    else:
        small = a * si * si - 2.0 * b * co * si + c * co * co
    return big, small, co, si


@njit(cache=True, error_model="numpy")
def _lam_power(v: float, t: float) -> float:
    return min(min(max(v, 1e-300), 1.0) ** t, 1.0 - 1e-6)


@njit(cache=True, error_model="numpy")
def steer(xn0, xn1, n11, n12, n22, xs0, xs1, s11, s12, s22, t, w11, w12, w22, per_metre, geodesic):
    """:meth:`..iteration.IterationMixin._steer` (2-D): the new mean and the
    entries of its covariance, (x0, x1, p11, p12, p22)."""
    x0 = xn0 + t * (xs0 - xn0)
    x1 = xn1 + t * (xs1 - xn1)
    if not geodesic:
        a = n11 + t * (s11 - n11)
        b = n12 + t * (s12 - n12)
        c = n22 + t * (s22 - n22)
        return x0, x1, a, b, c
    w = 1.0
    if per_metre:
        d0, d1 = x0 - xn0, x1 - xn1
        w = math.sqrt(d0 * d0 + d1 * d1)
    l11, l21, l22, ok = chol2(n11 + w * w11, n12 + w * w12, n22 + w * w22)
    if not ok:      # singular prior (P0 = 0 and no motion): keep the sample's P
        return x0, x1, s11, s12, s22
    i11, i21, i22 = inv_factor(l11, l21, l22)
    # M = L^-1 Ps L^-T
    m11 = i11 * i11 * s11
    m12 = i11 * (i21 * s11 + i22 * s12)
    m22 = i21 * (i21 * s11 + i22 * s12) + i22 * (i21 * s12 + i22 * s22)
    big, small, co, si = eigh2(m11, m12, m22)
    lb, ls = _lam_power(big, t), _lam_power(small, t)
    # LU = L [[co, -si], [si, co]]; P = LU diag(lb, ls) LU^T
    u11, u12 = l11 * co, -l11 * si
    u21, u22 = l21 * co + l22 * si, -l21 * si + l22 * co
    p11 = u11 * u11 * lb + u12 * u12 * ls
    p12 = u11 * u21 * lb + u12 * u22 * ls
    p22 = u21 * u21 * lb + u22 * u22 * ls
    return x0, x1, p11, p12, p22
