"""Matrix helpers of the NLP form (:mod:`.nlp_form`): the packing of a
lower-triangular or symmetric d x d matrix into its d (d + 1) / 2 entries,
its numeric stack (:func:`lower_stack`), a symmetrised symbolic inverse, and the numeric Cholesky factor of a
sensing matrix's PSD part (the L of a warm start's S = L L^T)."""

from __future__ import annotations

import casadi as ca
import numpy as np


def _tri_index(d: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(d) for j in range(i + 1)]


def _lower(v: ca.SX, tri: list, d: int) -> ca.SX:
    M = ca.SX.zeros(d, d)
    for p, (i, j) in enumerate(tri):
        M[i, j] = v[p]
    return M


def lower_stack(v: np.ndarray, tri: list, d: int) -> np.ndarray:
    """The numeric :func:`_lower` of every row of ``v`` (n, len(tri)): (n, d, d)."""
    v = np.asarray(v, float)
    M = np.zeros((v.shape[0], d, d))
    M[:, [i for i, _ in tri], [j for _, j in tri]] = v
    return M


def switched_off(L: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower-triangular factors (n, d, d) with their floor-level sensing
    switched off, and which columns are off (n, d): the polish's start
    (NLPProblem.switch_off). A column whose norm is at most ``level`` is
    zeroed. A step with more eigenvalues of S = L L^T at most level^2 than
    such columns (a diagonal at the floor with sensing below it, e.g.
    L = [[floor, 0], [-0.36, 0.63]]) is re-factored instead: S without its
    floor-level eigen-directions, as a lower-triangular factor whose last
    columns (one per dropped direction) are 0. Kept on, such a column let the polish
    creep along a rotation of (L_21, L_22) that leaves S unchanged as
    L_11 -> 0; pinned to the axes (the column zeroed, its sensing moved to
    the next one) the polish could not tilt the sensing direction and ended
    up to 6e-5 costlier (docs/numerics.md, "The polish's switch-off")."""
    d = L.shape[-1]
    off = np.linalg.norm(L, axis=1) <= level                          # (n, d): column norms
    out = np.where(off[:, None, :], 0.0, L)
    S = L @ L.transpose(0, 2, 1)
    n_floor = (np.linalg.eigvalsh(S) <= level ** 2).sum(axis=1)
    for n in np.flatnonzero(n_floor > off.sum(axis=1)):
        w, U = np.linalg.eigh(S[n])
        keep = w > level ** 2
        r = int(keep.sum())
        # S without them is B B^T (B = U_r sqrt(w_r), d x r); B^T = Q R gives the
        # lower-trapezoidal R^T with R^T R = B B^T (backward stable, no pivots):
        # its first r columns on, the rest off
        B = U[:, keep] * np.sqrt(w[keep])
        R = np.linalg.qr(B.T, mode="r")
        R *= np.where(np.diag(R) < 0, -1.0, 1.0)[:, None]
        out[n], off[n] = 0.0, np.arange(d) >= r
        out[n][:, :r] = R.T
    return out, off


def _symmetric(v: ca.SX, tri: list, d: int) -> ca.SX:
    M = ca.SX.zeros(d, d)
    for p, (i, j) in enumerate(tri):
        M[i, j] = v[p]
        M[j, i] = v[p]
    return M


def _sym_inv(M: ca.SX) -> ca.SX:
    """Inverse of a symmetric matrix expression, symmetrised."""
    Mi = ca.inv(M)
    return 0.5 * (Mi + Mi.T)


def _psd_factor(S: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the PSD part of S (a tiny jitter for S = 0);
    of each matrix of a stack (n, d, d) too."""
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    w, V = np.linalg.eigh(S)
    Sp = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
    # fmax: a NaN trace gives 1.0, as max(1.0, nan) did one matrix at a time
    jitter = 1e-12 * np.fmax(1.0, np.trace(Sp, axis1=-2, axis2=-1))
    return np.linalg.cholesky(Sp + jitter[..., None, None] * np.eye(S.shape[-1]))
