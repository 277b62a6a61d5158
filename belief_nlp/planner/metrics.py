"""Edge costs of IG-RRT*: travel + alpha * information, batched over nodes.

An edge (x1, P1) -> (x2, P2) predicts P_hat = P1 + W_e, with W_e = W_rate *
||x2 - x1|| (``per_metre``, the authors' planner) or W_e = W (``per_step``,
one time step per edge whatever its length), and is allowed only when it is
lossless, P2 <= P_hat: sensing can only shrink the covariance. Its cost is

    ||x2 - x1|| + alpha * I(P_hat, P2)

with I the chosen information metric:

* ``entropy``: 1/2 (log det P_hat - log det P2), the entropy reduction of the
  measurement, in nats (natural log, the smoothing paper's D_info) or bits.
  The authors' code computes (alpha/2) (log2 det P_hat - log2 det P2), i.e.
  alpha times the entropy reduction in bits = alpha * nats / ln 2. So their
  "metres + alpha/2 * bits" reads: bits of *log-determinant*, half of which is
  the entropy reduction in bits. For one path: cost_theirs = length + alpha *
  info_nats / ln 2, which is exactly our cost with ``info_unit="bits"``.
* ``wasserstein``: the Bures (covariance) part of the 2-Wasserstein distance
  between N(0, P2) and N(0, P_hat), metres (authors add 1e-6 under the root;
  we do not).
* ``hellinger``: the Hellinger distance between N(0, P2) and N(0, P_hat).

For the nearest-node search, where P2 need not be below P_hat, the authors'
matrix minimum of (P_hat, P2) stands in for P2 (see
:func:`belief_nlp.belief.matrix_minimum` and :mod:`.kernels`).
"""

from __future__ import annotations

import math

import numpy as np

from .. import belief
from .kernels import (_HALF, _ONE, _const, congruence_eigvals, lower_congruence_eig2, lower_congruence_eig2_coef,
                      lower_congruence_eig2_stack)

__all__ = ["EdgeMetric", "LOSSLESS_RTOL"]

# A transition counts as lossless when every generalised eigenvalue of
# (P_hat, P2) is >= 1 + LOSSLESS_RTOL. The small gap keeps the sensing matrix
# S = P2^-1 - P_hat^-1 of accepted edges safely PSD after rounding (the
# verifier rejects S with eigenvalues below -1e-8 of its norm).
LOSSLESS_RTOL = 1e-7
_LOSSLESS_MIN = _const(1.0 + LOSSLESS_RTOL)
_TINY = _const(1e-300)


class EdgeMetric:
    """Information term and cost scaling of one planner configuration.

    ``weight`` is the factor in front of the metric value in the edge cost:
    alpha, or alpha / ln 2 for entropy in bits (``weight0``: the same as a
    0-d array, for the batched costs).
    """

    def __init__(self, metric: str, alpha: float, info_unit: str, W_edge: np.ndarray):
        self.metric = metric
        self.alpha = float(alpha)
        self.info_unit = info_unit
        self.unit_factor = 1.0 / math.log(2.0) if (metric == "entropy" and info_unit == "bits") else 1.0
        self.weight = self.alpha * self.unit_factor
        self.weight0 = _const(self.weight)          # the same as a 0-d array (see kernels._const)
        self.W = np.asarray(W_edge, dtype=float)      # W_rate (per metre) or W (per step)
        self.trW = float(np.trace(self.W))

    # ------------------------------------------------------------ from lam
    def _from_lam(self, lam: np.ndarray) -> np.ndarray:
        """Metric value (in the metric's base unit: nats / 1) from generalised eigenvalues."""
        lam = np.maximum(lam, 1e-300)
        if self.metric == "entropy":
            return 0.5 * np.sum(np.log(lam), axis=-1)
        # hellinger: H^2 = 1 - prod lam^1/4 / ((1+lam)/2)^1/2 = -expm1(log BC)
        log_bc = np.sum(0.25 * np.log(lam) - 0.5 * np.log(0.5 * (1.0 + lam)), axis=-1)
        return np.sqrt(np.maximum(-np.expm1(log_bc), 0.0))

    # --------------------------------------------------- toward one child C
    def nearest_info(self, P: np.ndarray, w: np.ndarray, C: np.ndarray, C_Linv: np.ndarray) -> np.ndarray:
        """Information from every node (P_i + w_i W) to the sample C, with the
        matrix minimum standing in for C where the step is not lossless."""
        if self.metric == "wasserstein":
            P_hat = P + w[:, None, None] * self.W
            P_min = belief.matrix_minimum(P_hat, np.broadcast_to(C, P_hat.shape))
            return np.asarray(belief.wasserstein_distance(P_min, P_hat), dtype=float).reshape(-1)
        lam = congruence_eigvals(P, w, self.W, C_Linv)
        return self._from_lam(np.maximum(lam, 1.0))

    def edges_to(self, P: np.ndarray, w: np.ndarray, C: np.ndarray, C_L: np.ndarray,
                 C_Linv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lossless, info) of the edges from every node (P_i, weight w_i) to C."""
        lam = congruence_eigvals(P, w, self.W, C_Linv)
        lossless = lam[:, 0] >= 1.0 + LOSSLESS_RTOL
        if self.metric == "wasserstein":
            mu = congruence_eigvals(P, w, self.W, C_L.T)
            val = np.trace(C) + np.trace(P, axis1=1, axis2=2) + w * self.trW - 2.0 * np.sum(np.sqrt(np.maximum(mu, 0.0)), axis=1)
            return lossless, np.sqrt(np.maximum(val, 0.0))
        return lossless, self._from_lam(lam)

    # ------------------------------------------------ from one parent Q
    def edges_from(self, Q: np.ndarray, w: np.ndarray, P: np.ndarray, L: np.ndarray,
                   Linv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lossless, info) of the edges from one belief Q (weights w_i) to every node P_i."""
        Qs = np.broadcast_to(Q, P.shape)
        lam = congruence_eigvals(Qs, w, self.W, Linv)
        lossless = lam[:, 0] >= 1.0 + LOSSLESS_RTOL
        if self.metric == "wasserstein":
            mu = congruence_eigvals(Qs, w, self.W, np.swapaxes(L, -1, -2))
            val = (np.trace(P, axis1=1, axis2=2) + np.trace(Q) + w * self.trW
                   - 2.0 * np.sum(np.sqrt(np.maximum(mu, 0.0)), axis=1))
            return lossless, np.sqrt(np.maximum(val, 0.0))
        return lossless, self._from_lam(lam)

    # ------------------------------------ 2-D, from entries (closed form)
    # The same values as the methods above, bit for bit, from the entries
    # (s11, s12, s22) of the priors P_i + w_i W and the entries (t11, t21,
    # t22) of lower-triangular L^-1 factors (:func:`.kernels.lower_congruence_eig2`).
    # Not for "wasserstein" (``entries_ok``).

    @property
    def entries_ok(self) -> bool:
        """Whether the entry-based 2-D methods serve this metric."""
        return self.metric != "wasserstein"

    def _from_pair(self, small: np.ndarray, big: np.ndarray, floor: float) -> np.ndarray:
        if self.metric == "entropy":           # = _from_lam: a sum of two terms is their plain sum
            return _HALF * (np.log(np.maximum(small, floor)) + np.log(np.maximum(big, floor)))
        return self._from_lam(np.maximum(np.stack([small, big], axis=-1), floor))

    def nearest_info2(self, s11, s12, s22, t11: float, t21: float, t22: float) -> np.ndarray:
        """:meth:`nearest_info` from the priors' entries and the sample's L^-1 entries."""
        return self._from_pair(*lower_congruence_eig2(s11, s12, s22, t11, t21, t22), _ONE)

    def edges2(self, s11, s12, s22, t11, t21, t22) -> tuple[np.ndarray, np.ndarray]:
        """(lossless, info) of :meth:`edges_to` / :meth:`edges_from` from entries."""
        small, big = lower_congruence_eig2(s11, s12, s22, t11, t21, t22)
        return small >= _LOSSLESS_MIN, self._from_pair(small, big, _TINY)

    def nearest_info2_rows(self, S6: np.ndarray, t11: float, t21: float, t22: float) -> np.ndarray:
        """:meth:`nearest_info2` with the priors as the stack (s11, s11, s12, s11,
        s12, s22) (:func:`.kernels.lower_congruence_eig2_coef`; the same values)."""
        return self._from_pair(*lower_congruence_eig2_coef(S6, t11, t21, t22), _ONE)

    def edges2_rows(self, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`edges2` on the rows of S = (s11, s12, s22, t11, t21, t22)
        (:func:`.kernels.lower_congruence_eig2_stack`; the same values)."""
        small, big = lower_congruence_eig2_stack(S)
        return small >= _LOSSLESS_MIN, self._from_pair(small, big, _TINY)

    def cost(self, length: np.ndarray, info: np.ndarray) -> np.ndarray:
        """Edge cost: length + weight * info."""
        return length + self.weight0 * info
