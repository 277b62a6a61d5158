"""Batched small-matrix kernels of the planner.

Every iteration of IG-RRT* evaluates the edge cost between one belief and
every node of the tree. With d = 2 (the common case) numpy's batched
``eigvalsh``/``cholesky`` spend most of their time in per-matrix overhead, so
the 2-D kernels below work on the three distinct entries of each symmetric
matrix in closed form (about 25x faster on 2000 nodes); other dimensions use
numpy's batched linear algebra. Both branches compute the same quantities.

The central quantity is the set of generalised eigenvalues ``lam`` of a prior
P_hat with respect to a posterior candidate C: the eigenvalues of
L^-1 P_hat L^-T with C = L L^T. From them:

* the transition P_hat -> C is lossless (C <= P_hat) iff min(lam) >= 1;
* the entropy information 1/2 (log det P_hat - log det C) = 1/2 sum log lam;
* with the authors' matrix minimum C' of (P_hat, C), which stands in for C
  when the transition is not lossless, the generalised eigenvalues of P_hat
  w.r.t. C' are max(lam, 1), hence 1/2 sum log max(lam, 1);
* the Bhattacharyya coefficient of N(0, C) and N(0, P_hat) is
  prod lam^(1/4) / ((1 + lam)/2)^(1/2).
"""

from __future__ import annotations

import math

import numpy as np

# The reductions of the hot paths, called as ufunc methods: ndarray.any() and
# friends go through a Python wrapper that costs as much as the reduction on
# the planner's small arrays.
_any = np.logical_or.reduce
_all = np.logical_and.reduce
_min = np.minimum.reduce
_max = np.maximum.reduce


def _const(v: float) -> np.ndarray:
    """A read-only 0-d float array of v."""
    a = np.array(v)
    a.setflags(write=False)
    return a


# Constants of the hot elementwise paths as 0-d arrays: an array op with a
# Python (or numpy) scalar goes through numpy's scalar conversion and
# promotion, about 1-2 us more per call than with a 0-d array (and an int
# literal in a comparison more still); the values and results are the same.
_ZERO, _HALF, _ONE, _TWO = _const(0.0), _const(0.5), _const(1.0), _const(2.0)
_INF, _NINF = _const(np.inf), _const(-np.inf)

__all__ = ["ROWS_S", "congruence_eigvals", "chol2", "chol_lower", "chol_factors", "chol_pair2", "eigh2", "eigh_single",
           "inv_lower", "lower_congruence_eig2", "lower_congruence_eig2_coef", "lower_congruence_eig2_stack"]


def _cong2(s11, s12, s22, T):
    """Entries of T S T^T for symmetric 2x2 S given by its entries; T (2,2) or (n,2,2)."""
    t11, t12, t21, t22 = T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1]
    m11 = t11 * t11 * s11 + 2.0 * t11 * t12 * s12 + t12 * t12 * s22
    m12 = t11 * t21 * s11 + (t11 * t22 + t12 * t21) * s12 + t12 * t22 * s22
    m22 = t21 * t21 * s11 + 2.0 * t21 * t22 * s12 + t22 * t22 * s22
    return m11, m12, m22


def _eig2_pair(m11, m12, m22):
    """(smaller, larger) eigenvalues of symmetric 2x2 matrices from their entries.

    The larger root is computed directly, the smaller as det / larger, which
    avoids the cancellation of (tr - disc)/2 for ill-conditioned matrices.
    """
    half_tr = _HALF * (m11 + m22)
    m12sq = m12 * m12
    disc = np.sqrt(np.square(_HALF * (m11 - m22)) + m12sq)     # (x ** 2 is np.square)
    big = half_tr + disc
    det = m11 * m22 - m12sq
    if _all(big > _ZERO):     # always for positive definite input: no masked select needed
        return det / big, big
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(big > _ZERO, det / big, half_tr - disc), big


def _eig2(m11, m12, m22):
    """Ascending eigenvalues (..., 2) of symmetric 2x2 matrices from their entries."""
    return np.stack(_eig2_pair(m11, m12, m22), axis=-1)


def lower_congruence_eig2(s11, s12, s22, t11, t21, t22):
    """(smaller, larger) eigenvalues of T S T^T for 2x2 S = [[s11, s12], [s12, s22]]
    and lower-triangular T = [[t11, 0], [t21, t22]] (scalars or arrays).

    The same values as :func:`congruence_eigvals` bit for bit: there the
    terms with t12 are exact zeros added to the others, here they are left
    out, with the remaining products in the same order. A factor from
    :func:`chol_factors` or :func:`inv_lower` is exactly lower triangular.
    """
    m11 = t11 * t11 * s11
    m12 = t11 * t21 * s11 + t11 * t22 * s12
    m22 = t21 * t21 * s11 + _TWO * t21 * t22 * s12 + t22 * t22 * s22
    return _eig2_pair(m11, m12, m22)


# Rows of the six products of :func:`lower_congruence_eig2`, coefficient times
# entry: (t11 t11) s11, (t11 t21) s11, (t11 t22) s12, (t21 t21) s11, (2 t21 t22) s12,
# (t22 t22) s22. With the six in one (6, n) product the kernel is a few calls
# on a stack instead of a dozen on rows; every product and sum is the same.
# (index arrays, not lists: a list index is converted on every call)
ROWS_S = np.array([0, 0, 1, 0, 1, 2])        # s11, s11, s12, s11, s12, s22 of (s11, s12, s22)
_ROWS_TA = np.array([3, 3, 3, 4, 4, 5])      # t11, t11, t11, t21, t21 (doubled), t22 of (s.., t11, t21, t22)
_ROWS_TB = np.array([3, 4, 5, 4, 5, 5])      # t11, t21, t22, t21, t22, t22


def _eig2_from_products(prod: np.ndarray):
    """:func:`_eig2_pair` of the congruence from its six products (rows as ``ROWS_S``),
    summed as :func:`lower_congruence_eig2` sums them."""
    m22 = prod[3] + prod[4]
    m22 += prod[5]
    return _eig2_pair(prod[0], prod[1] + prod[2], m22)


def lower_congruence_eig2_coef(S6: np.ndarray, t11: float, t21: float, t22: float):
    """:func:`lower_congruence_eig2` for one factor (Python floats) and many
    priors given as the stack ``S6`` = (s11, s11, s12, s11, s12, s22) (6, n): the
    coefficients are formed in floats, as there, then one product."""
    c = np.array([[t11 * t11], [t11 * t21], [t11 * t22], [t21 * t21], [2.0 * t21 * t22], [t22 * t22]])
    return _eig2_from_products(c * S6)


def lower_congruence_eig2_stack(S: np.ndarray):
    """:func:`lower_congruence_eig2` on the rows of ``S`` = (s11, s12, s22, t11,
    t21, t22) (6, n), all arrays: coefficients (t_a t_b, with 2 t21 doubled
    first) and products in two stacked multiplications."""
    Ta = S.take(_ROWS_TA, axis=0)
    np.multiply(Ta[4], _TWO, out=Ta[4])
    prod = Ta * S.take(_ROWS_TB, axis=0)
    prod *= S.take(ROWS_S, axis=0)
    return _eig2_from_products(prod)


def congruence_eigvals(P: np.ndarray, w: np.ndarray | float, W: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Eigenvalues of T (P_i + w_i W) T^T for a stack P (n, d, d).

    ``w`` is a scalar or (n,) noise weight, ``W`` (d, d), ``T`` one (d, d)
    matrix or a stack (n, d, d). Returns (n, d), ascending.
    """
    if P.shape[-1] == 2:
        w = np.asarray(w, dtype=float)
        s11 = P[:, 0, 0] + w * W[0, 0]
        s12 = P[:, 0, 1] + w * W[0, 1]
        s22 = P[:, 1, 1] + w * W[1, 1]
        return _eig2(*_cong2(s11, s12, s22, T))
    S = P + np.asarray(w, dtype=float).reshape(-1, 1, 1) * W
    M = T @ S @ np.swapaxes(T, -1, -2)
    return np.linalg.eigvalsh(0.5 * (M + np.swapaxes(M, -1, -2)))


def chol_lower(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of one SPD matrix or a stack."""
    return np.linalg.cholesky(0.5 * (P + np.swapaxes(P, -1, -2)))


def inv_lower(L: np.ndarray) -> np.ndarray:
    """Inverse of lower-triangular matrices (one or a stack)."""
    if L.shape[-1] == 2:
        out = np.zeros_like(L)
        out[..., 0, 0] = 1.0 / L[..., 0, 0]
        out[..., 1, 1] = 1.0 / L[..., 1, 1]
        out[..., 1, 0] = -L[..., 1, 0] / (L[..., 0, 0] * L[..., 1, 1])
        return out
    return np.linalg.inv(L)


def chol2(a: float, b01: float, b10: float, c: float) -> tuple[float, float, float, float, float, float]:
    """Python floats (l11, l21, l22, det, big, b) of one 2x2 SPD matrix [[a, b01],
    [b10, c]] read symmetrically (b = (b01 + b10) / 2): its lower Cholesky
    factor, det P = (l11 l22)^2 and its larger eigenvalue ``big``. Raises
    ``np.linalg.LinAlgError`` when it is not positive definite."""
    b = 0.5 * (b01 + b10)
    if not a > 0:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    l11 = math.sqrt(a)
    l21 = b / l11
    r = c - l21 * l21
    if not r > 0:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    l22 = math.sqrt(r)
    half_tr = 0.5 * (a + c)
    big = half_tr + math.sqrt((0.5 * (a - c)) ** 2 + b * b)
    return l11, l21, l22, (l11 * l22) ** 2, big, b


def chol_pair2(l11: float, l21: float, l22: float) -> tuple[np.ndarray, np.ndarray]:
    """(L, L^-1) as 2x2 arrays from the entries of :func:`chol2` (one array
    allocation for both: they are views of a (2, 2, 2) stack)."""
    LL = np.array([[[l11, 0.0], [l21, l22]], [[1.0 / l11, 0.0], [-l21 / (l11 * l22), 1.0 / l22]]])
    return LL[0], LL[1]


def chol_factors(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(L, L^-1, log det P, smallest eigenvalue) of one SPD matrix.

    Raises ``np.linalg.LinAlgError`` when P is not positive definite. The 2-D
    case is done in scalar arithmetic (:func:`chol2`: a single 2x2 matrix
    costs far less in plain floats than in numpy calls).
    """
    if P.shape == (2, 2):
        (a, b01), (b10, c) = P.tolist()
        l11, l21, l22, det, big, _ = chol2(a, b01, b10, c)
        L, Linv = chol_pair2(l11, l21, l22)
        return L, Linv, math.log(det), det / big
    L = chol_lower(P)
    return L, inv_lower(L), 2.0 * float(np.sum(np.log(np.diagonal(L)))), float(np.linalg.eigvalsh(P)[0])


def eigh2(a: float, b01: float, b10: float, c: float) -> tuple[float, float, float, float]:
    """(larger eigenvalue, smaller eigenvalue, cos, sin) of one symmetric 2x2
    matrix [[a, b01], [b10, c]] read symmetrically, in Python floats: the
    Jacobi rotation angle theta = atan2(2b, a - c) / 2 gives the eigenvector
    (cos, sin) of the larger one, the smaller is det / larger (no
    cancellation) unless the larger is not positive."""
    b = 0.5 * (b01 + b10)
    th = 0.5 * math.atan2(2.0 * b, a - c)
    co, si = math.cos(th), math.sin(th)
    big = a * co * co + 2.0 * b * co * si + c * si * si      # along (co, si)
    small = (a * c - b * b) / big if big > 0 else a * si * si - 2.0 * b * co * si + c * co * co
    return big, small, co, si


def eigh_single(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and orthonormal eigenvectors (columns) of one symmetric matrix.

    2-D in closed form (:func:`eigh2`); otherwise ``np.linalg.eigh``.
    """
    if M.shape == (2, 2):
        (a, b01), (b10, c) = M.tolist()
        big, small, co, si = eigh2(a, b01, b10, c)
        return np.array([big, small]), np.array([[co, -si], [si, co]])
    return np.linalg.eigh(0.5 * (M + M.T))
