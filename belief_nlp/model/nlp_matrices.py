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


def without_columns(L: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Lower-triangular factors (n, d, d) with the columns ``off`` (n, d)
    switched off: the Cholesky factor of L L^T that skips those columns
    (each on column j takes what is left of S_jj and below after the
    earlier on columns). A switched-off column whose entries below the
    diagonal are 0 leaves the other columns as they are (copied, not
    recomputed); one with entries below moves that sensing onto the later
    columns, so S on the other directions is kept (a column's diagonal at
    the floor with L_ij != 0 below it left the polish a rotation of
    (L_ij, L_ii) that does not change S: IPOPT crept along it)."""
    out = np.where(off[:, None, :], 0.0, L)
    moved = off & (np.abs(np.tril(L, -1)).sum(axis=1) > 0)        # (n, d): sensing below a column switched off
    for n in np.flatnonzero(moved.any(axis=1)):
        S, Ln = L[n] @ L[n].T, np.zeros_like(L[n])
        for j in np.flatnonzero(~off[n]):
            v = S[j:, j] - Ln[j:, :j] @ Ln[j, :j]
            if v[0] > 0:
                Ln[j:, j] = v / np.sqrt(v[0])
        out[n] = Ln
    return out


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
