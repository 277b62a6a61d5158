"""The verifier's own distances (:mod:`belief_nlp.verify`): squared Mahalanobis
distances of sampled beliefs to half-spaces (closed form), polygons (whitened
vertices, point-to-segment distances, a winding test) and other polytopes
(Lawson & Hanson's least-distance problem via ``scipy.optimize.nnls``), and
the support function of a covariance. Deliberately shares no code with
:mod:`belief_nlp.geometry`, so that the two can check each other."""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from .polytope import Polytope

# Samples x polygon vertices handled at once by the 2-D distance (bounds memory).
_CHUNK_ENTRIES = 2_000_000

def _chol(P: np.ndarray) -> np.ndarray:
    d = P.shape[-1]
    jitter = 1e-30 * np.eye(d)
    sym = 0.5 * (P + np.swapaxes(P, -1, -2))
    try:
        return np.linalg.cholesky(sym + jitter)
    except np.linalg.LinAlgError:
        # Indefinite P(s) (only for paths already reported as inconsistent):
        # measure with the PSD part so that the report can still be built.
        w, V = np.linalg.eigh(sym)
        return np.linalg.cholesky((V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2) + jitter)


def _sqdist_halfspace(x: np.ndarray, P: np.ndarray, a: np.ndarray, beta: float) -> np.ndarray:
    """Samples (n, d), (n, d, d) to the obstacle {a^T y <= beta}."""
    t = x @ a - beta
    aPa = np.einsum("i,nij,j->n", a, P, a) + 1e-30
    return np.where(t <= 0, 0.0, t * t / aPa)


def _chol2(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(l11, l21, l22) of :func:`_chol` for stacked 2x2 matrices: in closed
    form with LAPACK's operations, so the same bits (a fifth of the stacked
    call's time), when every one is positive definite; else :func:`_chol`'s."""
    s00 = P[:, 0, 0] + 1e-30
    s10 = 0.5 * (P[:, 1, 0] + P[:, 0, 1])
    s11 = P[:, 1, 1] + 1e-30
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.sqrt(s00)
        c = s10 * (1.0 / a)                         # LAPACK's triangular solve: by the reciprocal
        e = s11 - c * c
    if np.all(s00 > 0) and np.all(e > 0):          # NaN fails both, as in LAPACK
        return a, c, np.sqrt(e)
    L = _chol(P)
    return L[:, 0, 0], L[:, 1, 0], L[:, 1, 1]


def _sqdist_polygon(x: np.ndarray, P: np.ndarray, V: np.ndarray,
                    chol: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
    """Samples (n, 2), (n, 2, 2) to a convex polygon with CCW vertices V (v, 2);
    ``chol``: :func:`_chol2` of P when the caller has it (shared by hazards)."""
    a, c, d_ = (v[:, None] for v in (chol if chol is not None else _chol2(P)))
    # whitened vertices w = L^-1 (v - x), per sample
    w0 = (V[None, :, 0] - x[:, :1]) / a
    w1 = (V[None, :, 1] - x[:, 1:] - c * w0) / d_
    e0 = np.roll(w0, -1, axis=1) - w0                                     # edges
    e1 = np.roll(w1, -1, axis=1) - w1
    # origin inside iff it lies left of (or on) every CCW edge (whitening keeps orientation: det L > 0)
    inside = np.all(e0 * (-w1) - e1 * (-w0) >= 0, axis=1)
    t = np.clip(-(w0 * e0 + w1 * e1) / np.maximum(e0 * e0 + e1 * e1, 1e-300), 0, 1)
    q0 = w0 + t * e0
    q1 = w1 + t * e1
    dist2 = np.min(q0 * q0 + q1 * q1, axis=1)
    return np.where(inside, 0.0, dist2)


def _sqdist_ldp(x: np.ndarray, P: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-distance programming via NNLS, one sample at a time.

    min ||u||^2 s.t. (A L) u <= b - A x. Lawson-Hanson: with G = -(A L),
    h = -(b - A x), solve NNLS min ||E w - f||, E = [G^T; h^T], f = e_{d+1};
    then u = -r[:d] / r[d] with r = E w - f (infeasible when r = 0).
    """
    out = np.empty(x.shape[0])
    d = x.shape[1]
    f = np.zeros(d + 1)
    f[-1] = 1.0
    for i in range(x.shape[0]):
        L = _chol(P[i])
        c = b - A @ x[i]
        if np.all(c >= 0):
            out[i] = 0.0
            continue
        G = -(A @ L)
        h = -c
        E = np.vstack([G.T, h[None, :]])
        try:
            w, _ = nnls(E, f, maxiter=50 * (A.shape[0] + d))
        except (RuntimeError, ValueError):  # no convergence, or non-finite data: undecided
            out[i] = np.nan
            continue
        r = E @ w - f
        if abs(r[-1]) < 1e-300:
            out[i] = np.inf
            continue
        u = -r[:d] / r[-1]
        out[i] = float(u @ u)
    return out


def _sqdist(x: np.ndarray, P: np.ndarray, poly: Polytope, chol: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
    """Squared Mahalanobis distances of samples (n, d), (n, d, d) to ``poly``;
    ``chol``: :func:`_chol2` of P (2-D), for callers that measure several
    polygons from the same samples."""
    if poly.n_faces == 1:
        return _sqdist_halfspace(x, P, poly.A[0], float(poly.b[0]))
    if poly.dim == 2 and poly.vertices is not None:
        # (samples x vertices) temporaries: chunk so that memory stays bounded
        step = max(1, _CHUNK_ENTRIES // poly.vertices.shape[0])
        return np.concatenate([_sqdist_polygon(x[i:i + step], P[i:i + step], poly.vertices,
                                               None if chol is None else tuple(v[i:i + step] for v in chol))
                               for i in range(0, x.shape[0], step)])
    return _sqdist_ldp(x, P, poly.A, poly.b)


def _support(P: np.ndarray, A: np.ndarray) -> np.ndarray:
    """||P^1/2 a|| for each row a of A, via eigendecomposition."""
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    R = (V * np.sqrt(np.maximum(w, 0.0))) @ V.T
    return np.linalg.norm(A @ R, axis=1)


def _psd_part(P: np.ndarray, rtol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Nearest symmetric PSD matrices of a stack, and which ones were not PSD
    (asymmetric or with an eigenvalue below -rtol * norm)."""
    sym = 0.5 * (P + np.swapaxes(P, -1, -2))
    norm = np.maximum(np.linalg.norm(P, axis=(-2, -1)), 1e-300)
    asym = np.linalg.norm(P - sym, axis=(-2, -1)) > rtol * norm
    w, V = np.linalg.eigh(sym)
    neg = w[..., 0] < -rtol * norm
    fixed = np.where(neg[:, None, None], (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2), sym)
    return fixed, asym | neg
