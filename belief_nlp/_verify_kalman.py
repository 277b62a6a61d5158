"""The verifier's Kalman-consistency and sensing checks of a whole path
(:mod:`belief_nlp.verify`), batched over the steps."""

from __future__ import annotations

import numpy as np

from . import belief
from .path import BeliefPath


def _per_step(fn, n: int, failed: float) -> np.ndarray:
    out = np.empty(n)
    for k in range(n):
        try:
            out[k] = fn(k)
        except np.linalg.LinAlgError:
            out[k] = failed
    return out


def kalman_checks(path: BeliefPath) -> tuple[np.ndarray, np.ndarray]:
    """Per step k = 1..K: the relative residual of P_k against the Kalman
    update of P_prior_k and S_k (inf where that update fails), and S_k's
    smallest eigenvalue over its norm (NaN where it cannot be computed).

    One batched call for the whole path (a K = 20 path's step-by-step loop
    took ~5 ms of a 0.12 s re-plan); step by step only when the batch fails,
    since then it raises for every step (a prior that is not PSD)."""
    K = path.K
    Pp, S, P = path.P_prior[1:], path.S[1:], path.P[1:]
    Pn = np.maximum(np.linalg.norm(P, axis=(1, 2)), 1e-300)
    Sn = np.linalg.norm(S, axis=(1, 2))
    try:
        kal = np.linalg.norm(belief.update(Pp, S) - P, axis=(1, 2)) / Pn
    except np.linalg.LinAlgError:  # a prior not PSD, or P_prior^-1 + S singular
        kal = _per_step(lambda k: np.linalg.norm(belief.update(Pp[k], S[k]) - P[k]) / Pn[k], K, np.inf)
    try:
        smin = np.linalg.eigvalsh(S)[:, 0] / np.where(Sn > 0, Sn, 1.0)
    except np.linalg.LinAlgError:
        smin = _per_step(lambda k: np.linalg.eigvalsh(S[k])[0] / (Sn[k] if Sn[k] > 0 else 1.0), K, np.nan)
    return kal, np.where(Sn > 0, smin, 0.0)
