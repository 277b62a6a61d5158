"""Gaussian belief maths: Kalman prediction/update, sensing, information costs.

All functions are batched: covariances may be (d, d) or (..., d, d) stacks.
Information is measured in nats (natural log), as in the smoothing paper;
divide by ln 2 for the bits the authors' IG-RRT* reports.

Paper references: prediction P_hat = P + W and update P = (P_hat^-1 + S)^-1
(section II.A); steering cost D_k = ||x_k - x_{k-1}||^2 + alpha * D_info,k
with D_info,k = 1/2 (log det P_hat_k - log det P_k) (section II.B).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "predict",
    "update",
    "lossless_sensing",
    "is_lossless",
    "information_cost",
    "logdet",
    "steering_cost",
    "path_steering_cost",
    "matrix_minimum",
    "wasserstein_distance",
    "hellinger_distance",
    "NATS_PER_BIT",
]

NATS_PER_BIT = math.log(2.0)


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def _eye_like(M: np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.eye(M.shape[-1]), M.shape)


def logdet(P) -> np.ndarray:
    """log det of SPD matrices via Cholesky (raises LinAlgError if not PD)."""
    L = np.linalg.cholesky(np.asarray(P, dtype=float))
    return 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)


def predict(P, W):
    """Prior covariance after one step: P_hat = P + W."""
    return np.asarray(P, dtype=float) + np.asarray(W, dtype=float)


def update(P_prior, S):
    """Posterior after sensing with information S >= 0: (P_prior^-1 + S)^-1.

    Computed as L (I + L^T S L)^-1 L^T with P_prior = L L^T, so a tiny or
    singular prior (P0 = 1e-9 I or 0) never gets inverted. Where S is exactly
    zero the prior is returned unchanged.
    """
    P_prior = np.asarray(P_prior, dtype=float)
    S = np.asarray(S, dtype=float)
    if not S.any() and S.shape[-2:] == P_prior.shape[-2:]:
        # nothing sensed anywhere (most steps of a minimal-sensing path): the
        # result below, without its ~0.2 ms of small-matrix calls per step
        return np.array(np.broadcast_to(P_prior, np.broadcast_shapes(P_prior.shape, S.shape)))
    L = _chol_psd(P_prior)
    M = _eye_like(P_prior) + np.swapaxes(L, -1, -2) @ S @ L
    out = _sym(L @ np.linalg.solve(M, np.swapaxes(L, -1, -2)))
    # No measurement (S exactly 0): the posterior is the prior, bit for bit,
    # so such steps carry exactly zero information cost.
    no_sensing = np.all(S == 0, axis=(-2, -1))
    if np.any(no_sensing):
        out = np.where(no_sensing[..., None, None], P_prior, out)
    return out


def _chol_psd(P: np.ndarray) -> np.ndarray:
    """Cholesky factor that tolerates PSD (singular) input via a tiny shift."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        scale = np.maximum(np.trace(P, axis1=-2, axis2=-1), 1e-300)[..., None, None]
        return np.linalg.cholesky(P + 1e-15 * scale * _eye_like(P) + 1e-300 * _eye_like(P))


def lossless_sensing(P_prior, P_post):
    """Sensing information S = P_post^-1 - P_prior^-1 of a lossless transition.

    Evaluated as L^-T (M^-1 - I) L^-1 with P_prior = L L^T and
    M = L^-1 P_post L^-T, which keeps the subtraction well conditioned. The
    result is PSD iff P_post <= P_prior (see :func:`is_lossless`).
    """
    P_prior = np.asarray(P_prior, dtype=float)
    P_post = np.asarray(P_post, dtype=float)
    L = np.linalg.cholesky(P_prior)
    Linv = np.linalg.inv(L)
    M = _sym(Linv @ P_post @ np.swapaxes(Linv, -1, -2))
    Minv = np.linalg.inv(M)
    return _sym(np.swapaxes(Linv, -1, -2) @ (Minv - _eye_like(M)) @ Linv)


def is_lossless(P_prior, P_post, rtol: float = 1e-9) -> np.ndarray | bool:
    """Whether P_post <= P_prior in the matrix order (sensing can only shrink P).

    Checks the largest generalised eigenvalue of (P_post, P_prior) <= 1 + rtol.
    """
    P_prior = np.asarray(P_prior, dtype=float)
    P_post = np.asarray(P_post, dtype=float)
    L = np.linalg.cholesky(P_prior)
    Linv = np.linalg.inv(L)
    M = _sym(Linv @ P_post @ np.swapaxes(Linv, -1, -2))
    out = np.linalg.eigvalsh(M)[..., -1] <= 1.0 + rtol
    return bool(out) if np.ndim(out) == 0 else out


def information_cost(P_prior, P_post) -> np.ndarray | float:
    """1/2 (log det P_prior - log det P_post) in nats (>= 0 for lossless steps).

    Both log-determinants come from Cholesky factors, so tiny covariances
    (1e-9 I) lose no precision.
    """
    P_prior = np.asarray(P_prior, dtype=float)
    P_post = np.asarray(P_post, dtype=float)
    out = 0.5 * (logdet(P_prior) - logdet(P_post))
    return float(out) if np.ndim(out) == 0 else out


def steering_cost(x_prev, x_next, P_prior, P_post, alpha: float):
    """Per-step cost of the smoothing paper: ||dx||^2 + alpha * D_info (nats)."""
    dx = np.asarray(x_next, dtype=float) - np.asarray(x_prev, dtype=float)
    return np.sum(dx * dx, axis=-1) + alpha * information_cost(P_prior, P_post)


def path_steering_cost(x, P_prior, P_post, alpha: float) -> tuple[float, float, float]:
    """(total, control, information) of a path: x (K+1, d), P_prior/P_post (K+1, d, d).

    Index 0 is the start and carries no cost.
    """
    x = np.asarray(x, dtype=float)
    control = float(np.sum(np.diff(x, axis=0) ** 2))
    info = float(np.sum(information_cost(np.asarray(P_prior)[1:], np.asarray(P_post)[1:])))
    return control + alpha * info, control, info


def matrix_minimum(P1, P2):
    """The authors' "matrix minimum": a largest covariance below both P1 and P2.

    With P2 = L L^T and L^-1 P1 L^-T = U D U^T, returns L U min(D, I) U^T L^T.
    (Equal to P2^1/2 U' min(D, I) U'^T P2^1/2 of their planner: the result does
    not depend on the square root used.) Both arguments must be PD.
    """
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    L = np.linalg.cholesky(P2)
    Linv = np.linalg.inv(L)
    D, U = np.linalg.eigh(_sym(Linv @ P1 @ np.swapaxes(Linv, -1, -2)))
    Dm = np.minimum(D, 1.0)
    inner = (U * Dm[..., None, :]) @ np.swapaxes(U, -1, -2)
    return _sym(L @ inner @ np.swapaxes(L, -1, -2))


def _sqrtm_psd(P: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(_sym(P))
    return (V * np.sqrt(np.maximum(w, 0.0))[..., None, :]) @ np.swapaxes(V, -1, -2)


def wasserstein_distance(P1, P2, x1=None, x2=None):
    """2-Wasserstein distance between N(x1, P1) and N(x2, P2), in metres.

    sqrt(||x1 - x2||^2 + tr P1 + tr P2 - 2 tr (P2^1/2 P1 P2^1/2)^1/2); without
    means (the default) only the covariance (Bures) part.
    """
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    R = _sqrtm_psd(P2)
    cross = np.trace(_sqrtm_psd(R @ P1 @ R), axis1=-2, axis2=-1)
    val = np.trace(P1, axis1=-2, axis2=-1) + np.trace(P2, axis1=-2, axis2=-1) - 2 * cross
    val = np.maximum(val, 0.0)
    if x1 is not None or x2 is not None:
        dx = _mean_difference(x1, x2)
        val = val + np.sum(dx * dx, axis=-1)
    return np.sqrt(val)


def _mean_difference(x1, x2) -> np.ndarray:
    if x1 is None or x2 is None:
        raise ValueError("give both means x1 and x2, or neither")
    return np.asarray(x1, dtype=float) - np.asarray(x2, dtype=float)


def hellinger_distance(P1, P2, x1=None, x2=None):
    """Hellinger distance between N(x1, P1) and N(x2, P2), in [0, 1].

    H^2 = 1 - BC with the Bhattacharyya coefficient
    BC = det(P1)^1/4 det(P2)^1/4 / det(Pm)^1/2 exp(-1/8 dx^T Pm^-1 dx),
    Pm = (P1 + P2)/2; zero-mean Gaussians when the means are omitted.
    Both covariances must be positive definite.
    """
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    Pm = 0.5 * (P1 + P2)
    log_bc = 0.25 * logdet(P1) + 0.25 * logdet(P2) - 0.5 * logdet(Pm)
    if x1 is not None or x2 is not None:
        dx = _mean_difference(x1, x2)
        dx_b = np.broadcast_to(dx, Pm.shape[:-1])
        sol = np.linalg.solve(Pm, dx_b[..., None])[..., 0]
        log_bc = log_bc - 0.125 * np.sum(dx_b * sol, axis=-1)
    # 1 - exp(t) via expm1: no cancellation when the two are nearly equal.
    return np.sqrt(np.maximum(-np.expm1(log_bc), 0.0))
