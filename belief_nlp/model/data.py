"""Scenario data and points of the model, in the model's scaled units.

Units (docs/numerics.md, "Scaling"): every length is divided by
sigma = sqrt(max eig W), so x' = x / sigma, P' = P / sigma^2, W' = W / sigma^2
(~ I), Q' = sigma^2 Q and a certificate scales as lam' = sigma lam. The cost
sum ||dx||^2 + alpha/2 sum (log det Y_k - log det Q_k) becomes
sigma^2 sum ||dx'||^2 + the (scale-free) information term. In metres, W ~ 2e-4
and P0^-1 ~ 1e9 break both Clarabel and IPOPT.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ValidationError
from ..scenario import Scenario

__all__ = ["ProblemData", "Layout", "sym", "psd_part", "surrogate_information"]


@dataclass(frozen=True)
class ProblemData:
    """Scenario data in scaled units, hazards padded to a common face count."""

    sigma: float
    chi2: float
    alpha: float
    K: int
    d: int
    x0: np.ndarray            # (d,)
    P0: np.ndarray            # (d, d)
    W: np.ndarray             # (d, d)
    A: np.ndarray             # (J, F, d) hazard normals (padded rows zero)
    b: np.ndarray             # (J, F)
    face_mask: np.ndarray     # (J, F) bool
    hazard_names: tuple
    At: np.ndarray            # (N, d) target normals
    bt: np.ndarray            # (N,)
    chi2_target: float = float("nan")   # containment level (the scenario's; NaN: chi2)
    budget: float | None = None         # end-to-end risk budget: per-pair levels are variables
    continuous: bool = False            # levels asked under Sigma_k at both ends (risk.continuous_surrogate)
    chi2_start: float = float("nan")    # level of transition 1, both ends (scenario.chi2_start; NaN: chi2)

    def __post_init__(self) -> None:
        if not np.isfinite(self.chi2_target):
            object.__setattr__(self, "chi2_target", float(self.chi2))
        if not np.isfinite(self.chi2_start):
            object.__setattr__(self, "chi2_start", float(self.chi2))

    @property
    def relief(self) -> float:
        """chi2 - chi2_start >= 0: how much lower transition 1's rows are held
        than every other pair's (a start datum, like x0: a parameter of every
        form, not part of the cache key)."""
        return max(float(self.chi2) - float(self.chi2_start), 0.0)

    def collision_levels(self) -> np.ndarray:
        """(K, 1) level of each transition as the checks judge it: chi2, and
        chi2_start for transition 1 (broadcasts against (K, J))."""
        lv = np.full((self.K, 1), float(self.chi2))
        lv[0] = min(float(self.chi2_start), float(self.chi2))
        return lv

    @classmethod
    def from_scenario(cls, scenario: Scenario, K: int, alpha: float | None = None, chi2: float | None = None,
                      budget: float | None = None, continuous: bool = False) -> "ProblemData":
        """The scaled data of ``scenario`` at horizon K. ``chi2`` overrides the
        collision level (the target keeps the scenario's); ``budget`` makes every
        pair's level a decision variable under sum_kj g(tau_kj) <= budget
        (:mod:`belief_nlp.allocation`; ``chi2`` is then the warm start's level);
        ``continuous``: each pair's level holds at both ends of its transition
        under Sigma_k = P_prior_{k-1} + W (the continuous-time surrogate)."""
        relaxed = getattr(scenario, "start_confidence", None) is not None
        if relaxed and (budget is not None or continuous or chi2 is not None):
            raise ValidationError("start.confidence", "a start held to its own level cannot be combined with a "
                                                      "risk budget or another collision level")
        W = np.asarray(scenario.W, float)
        sigma = float(np.sqrt(np.max(np.linalg.eigvalsh(W))))
        hz = scenario.hazards
        F = max(h.n_faces for h in hz)
        J = len(hz)
        d = scenario.dim
        A = np.zeros((J, F, d))
        b = np.zeros((J, F))
        mask = np.zeros((J, F), bool)
        for j, h in enumerate(hz):
            A[j, : h.n_faces] = h.A
            b[j, : h.n_faces] = h.b / sigma
            mask[j, : h.n_faces] = True
        return cls(
            sigma=sigma, chi2=float(scenario.chi2 if chi2 is None else chi2),
            alpha=float(scenario.alpha if alpha is None else alpha), K=int(K), d=d,
            x0=scenario.x0 / sigma, P0=scenario.P0 / sigma**2, W=W / sigma**2,
            A=A, b=b, face_mask=mask, hazard_names=tuple(h.name for h in hz),
            At=scenario.target.A.copy(), bt=scenario.target.b / sigma,
            chi2_target=float(scenario.chi2), budget=None if budget is None else float(budget),
            continuous=bool(continuous), chi2_start=float(scenario.chi2_start) if relaxed else float("nan"),
        )

    @property
    def J(self) -> int:
        return int(self.A.shape[0])

    @property
    def F(self) -> int:
        return int(self.A.shape[1])

    @property
    def n_pairs(self) -> int:
        return self.K * self.J

    @cached_property
    def level_bounds(self) -> tuple[float, float]:
        """(tau_lo, tau_hi) of the per-pair levels (:func:`belief_nlp.allocation.level_bounds`);
        budget mode only."""
        from ..allocation import level_bounds

        return level_bounds(float(self.budget), self.n_pairs)

    @cached_property
    def T2(self) -> np.ndarray:
        """Sigma_2^-1 = (P0 + 2 W)^-1: the continuous surrogate's information
        matrix of transition 2 (Sigma_1^-1 is Q1)."""
        return np.linalg.inv(self.P0 + 2 * self.W)

    @cached_property
    def Q1(self) -> np.ndarray:
        """Fixed prior information of step 1, (P0 + W)^-1 (C8)."""
        return np.linalg.inv(self.P0 + self.W)


@dataclass
class Layout:
    """A point of the model in scaled units (k = 0..K; index 0 holds constants)."""

    x: np.ndarray     # (K+1, d)
    Q: np.ndarray     # (K+1, d, d) prior information (Q[0] unused, Q[1] fixed)
    S: np.ndarray     # (K+1, d, d) sensing information (S[0] = 0)
    lam: np.ndarray   # (K, J, F) certificates of transitions 1..K (padded faces 0)
    tau: np.ndarray | None = None   # (K, J) per-pair levels (budget mode only)

    @property
    def Y(self) -> np.ndarray:
        return self.Q + self.S

    def copy(self) -> "Layout":
        return Layout(self.x.copy(), self.Q.copy(), self.S.copy(), self.lam.copy(),
                      None if self.tau is None else self.tau.copy())

    def with_prefix(self, offset: int, x0: np.ndarray, Q_prefix: np.ndarray) -> "Layout":
        """This point after ``offset`` steps held at the mean ``x0`` with prior
        information ``Q_prefix``, no sensing and no certificates (a frozen
        prefix: :mod:`.nlp_prefix`, :mod:`.conic_prefix`; without levels)."""
        d = self.x.shape[1]
        return Layout(np.vstack([np.tile(x0, (offset + 1, 1)), self.x[1:]]),
                      np.concatenate([np.zeros((1, d, d)), np.tile(Q_prefix, (offset, 1, 1)), self.Q[1:]]),
                      np.concatenate([np.zeros((offset + 1, d, d)), self.S[1:]]),
                      np.concatenate([np.zeros((offset,) + self.lam.shape[1:]), self.lam]))

    def tail(self, offset: int, Q1: np.ndarray) -> "Layout":
        """The steps after the first ``offset`` as a point of their own, its
        fixed Q_1 = ``Q1`` (the inverse of :meth:`with_prefix`)."""
        d = self.x.shape[1]
        Q = np.concatenate([np.zeros((1, d, d)), self.Q[offset + 1:]])
        Q[1] = Q1
        return Layout(self.x[offset:].copy(), Q, np.concatenate([np.zeros((1, d, d)), self.S[offset + 1:]]),
                      self.lam[offset:].copy(), None if self.tau is None else self.tau[offset:].copy())


def sym(M: np.ndarray) -> np.ndarray:
    """Symmetric part of a (batch of) square matrices."""
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def psd_part(M: np.ndarray) -> np.ndarray:
    """Projection of a (batch of) symmetric matrices on the PSD cone."""
    w, V = np.linalg.eigh(M)
    return (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)


def surrogate_information(D: ProblemData, Q: np.ndarray) -> np.ndarray:
    """(K, d, d) T_k = Sigma_k^-1 of the continuous-time surrogate from the priors
    Q (K+1, d, d): T_1 = Q_1, T_k = (Q_{k-1}^-1 + W)^-1 (Sigma_k = P_prior_{k-1} + W,
    :func:`belief_nlp.risk.surrogate_covariances`)."""
    T = np.empty((D.K, D.d, D.d))
    T[0] = D.Q1
    if D.K > 1:
        T[1:] = sym(np.linalg.inv(np.linalg.inv(Q[1:-1]) + D.W))
    return T
