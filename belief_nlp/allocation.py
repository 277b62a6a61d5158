"""An end-to-end collision-probability budget allocated across transition-hazard
pairs (the paper's stated future work; issue 20, items 2-3).

Each pair (k, j) -- transition k, hazard j -- gets its own confidence level
tau_kj (a squared Mahalanobis radius) instead of the paper's one chi2. A pair
whose certified clearance is at least tau_kj has an instantaneous collision
probability of at most g(tau_kj), g(tau) = Phi_bar(sqrt(tau)) (convex and
decreasing; :func:`belief_nlp.risk.gaussian_tail`), so

    sum_kj g(tau_kj) <= Delta

bounds the probability of being inside some hazard at the step times by
Boole's inequality (:mod:`belief_nlp.risk`, ``step_time``).

* ``allocation="optimal"``: the tau_kj are decision variables of the one
  symbolic model (:mod:`belief_nlp.model.doc`, :mod:`belief_nlp.model.nlp_form`)
  in [tau_lo, tau_hi] (:func:`level_bounds`); the NLP uses g exactly, each
  CCP step a convex quadratic majorant of g tight at the current levels
  (g is convex with g'' decreasing, so g''(tau~/2) bounds its curvature on
  tau >= tau~/2), so every CCP iterate is certified and the step stays DPP.
* ``allocation="uniform"``: every pair at tau = g^-1(Delta / (K J)), the
  paper's fixed-level problem at that level.

``kind="continuous"`` budgets the continuous-time bound instead (touching a
hazard at any instant, with feedback on the estimate; ``RiskBound.continuous``)
through a per-pair surrogate: each pair's level is asked of both ends of the
transition under the one covariance Sigma_k = P_prior_{k-1} + W_k (at least
the state's deviation from plan anywhere in the transition), and then the
pair's crossing probability is at most CONTINUOUS_FACTOR g(tau_kj)
(:func:`belief_nlp.risk.continuous_surrogate`, derivation in docs/safety.md),
so the model's budget is Delta / CONTINUOUS_FACTOR.

The target containment keeps the scenario's own confidence (it is not a
collision). The reported bound is never the model's: it is recomputed from
the answer's certified clearances (:func:`belief_nlp.risk.path_risk`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from .errors import ValidationError
from .risk import gaussian_tail

__all__ = ["RiskBudget", "RiskAllocation", "tail", "level_for", "level_bounds", "ALLOCATIONS", "RISK_KINDS",
           "CONTINUOUS_FACTOR"]

ALLOCATIONS = ("optimal", "uniform")
RISK_KINDS = ("steps", "continuous")
CONTINUOUS_FACTOR = 3.0     # crossing probability <= 3 g(level under Sigma_k) per pair (risk.continuous_surrogate)
# Smallest tail value a pair is modelled with, relative to Delta / (K J): below
# it the bound is the constant g(tau_hi) (a pair far from every hazard).
FLOOR = 1e-3


def tail(tau: np.ndarray | float) -> np.ndarray:
    """g(tau) = Phi_bar(sqrt(tau)): the instantaneous collision bound of a pair
    certified at level tau (1 for tau <= 0); the same function as
    :func:`belief_nlp.risk.gaussian_tail`, which reports it."""
    return gaussian_tail(tau)


def level_for(p: np.ndarray | float) -> np.ndarray:
    """g^-1(p): the level tau whose tail is p (0 < p < 1/2)."""
    p = np.asarray(p, dtype=float)
    return ndtri(p) ** 2


def level_bounds(budget: float, n_pairs: int) -> tuple[float, float]:
    """(tau_lo, tau_hi): the range a pair's level is optimised in. tau_lo =
    g^-1(budget) (no single pair may spend more than the whole budget);
    tau_hi = g^-1(FLOOR budget / n_pairs), beyond which a pair's risk is
    negligible (capping there leaves no free direction to a pair far from
    its hazard; together the capped pairs spend at most FLOOR budget)."""
    return float(level_for(budget)), float(level_for(FLOOR * budget / max(int(n_pairs), 1)))


@dataclass(frozen=True)
class RiskBudget:
    """A collision-probability budget for a whole path.

    Parameters
    ----------
    budget : float
        Delta in (0, 1/2): the end-to-end probability the path may spend.
    allocation : {"optimal", "uniform"}
        Per-pair levels chosen by the smoother (decision variables) or split
        equally over the K J pairs.
    kind : {"steps", "continuous"}
        What the budget bounds: "steps", the probability of being inside some
        hazard at the K + 1 step times (``RiskBound.step_time``);
        "continuous", the probability of touching some hazard at any instant
        (``RiskBound.continuous``), through the per-pair surrogate of the
        module doc (costlier paths: each pair's level holds under a larger
        covariance, and a pair spends up to 3 g(tau)).
    """

    budget: float
    allocation: str = "optimal"
    kind: str = "steps"

    def __post_init__(self) -> None:
        b = self.budget
        if isinstance(b, bool) or not isinstance(b, (int, float, np.integer, np.floating)):
            raise ValidationError("risk", f"must be a number in (0, 0.5), got {b!r:.40}")
        if not math.isfinite(float(b)) or not 0 < float(b) < 0.5:
            raise ValidationError("risk", f"must be a finite number in (0, 0.5) (an end-to-end collision "
                                          f"probability), got {b!r:.40}")
        object.__setattr__(self, "budget", float(b))
        if not isinstance(self.allocation, str) or self.allocation.lower() not in ALLOCATIONS:
            raise ValidationError("allocation", f"must be one of {ALLOCATIONS}, got {self.allocation!r:.40}")
        object.__setattr__(self, "allocation", self.allocation.lower())
        if not isinstance(self.kind, str) or self.kind.lower() not in RISK_KINDS:
            raise ValidationError("risk_kind", f"must be one of {RISK_KINDS}, got {self.kind!r:.40}")
        object.__setattr__(self, "kind", self.kind.lower())

    @property
    def model_budget(self) -> float:
        """What the model's levels may spend, sum_kj g(tau_kj): the budget, or
        for ``kind="continuous"`` the budget / CONTINUOUS_FACTOR."""
        return self.budget / CONTINUOUS_FACTOR if self.kind == "continuous" else self.budget

    @property
    def factor(self) -> float:
        """Risk a pair spends per unit of g(tau): 1, or CONTINUOUS_FACTOR."""
        return CONTINUOUS_FACTOR if self.kind == "continuous" else 1.0

    def uniform_level(self, n_pairs: int) -> float:
        """tau of the uniform allocation: g(tau) = model budget / n_pairs."""
        return float(level_for(self.model_budget / n_pairs))

    def warm_level(self, n_pairs: int) -> float:
        """The first level tried for the warm start of an optimal allocation:
        uniform at 90 % of the model budget (slack for the first steps)."""
        return float(level_for(0.9 * self.model_budget / n_pairs))


@dataclass(eq=False)
class RiskAllocation:
    """How a smoothed path spends its collision-probability budget.

    Attributes
    ----------
    budget : float
        Delta, the end-to-end budget.
    allocation : ndarray, shape (K, J)
        Risk allotted to each transition-hazard pair: g(levels) (kind
        "continuous": CONTINUOUS_FACTOR g(levels)).
    levels : ndarray, shape (K, J)
        Each pair's confidence level tau_kj (squared Mahalanobis radius).
    bound : float
        The certified end-to-end bound of the returned path, recomputed from
        the path (:func:`belief_nlp.risk.path_risk`): ``step_time`` (the
        Boole sum of g(clearance)) or, kind "continuous", ``continuous``;
        <= budget.
    method : str
        "optimal" or "uniform".
    kind : str
        What the budget bounds ("steps" or "continuous").
    hazard_names : list of str
        Names of the J hazards (the columns).
    """

    budget: float
    allocation: np.ndarray
    levels: np.ndarray
    bound: float
    method: str
    kind: str = "steps"
    hazard_names: tuple = ()

    @property
    def per_transition(self) -> np.ndarray:
        """(K,) allotted risk per transition (sum over hazards)."""
        return np.sum(self.allocation, axis=1)

    @property
    def allotted(self) -> float:
        """Sum of the allocation (<= budget)."""
        return float(np.sum(self.allocation))

    def summary(self) -> str:
        """One line: the budget, the method, the certified bound and the allotted sum."""
        return (f"risk budget {self.budget:.3g} ({self.method} allocation, {self.kind}): certified bound "
                f"{self.bound:.3g}, allotted {self.allotted:.3g}")

    def to_dict(self) -> dict:
        """JSON-ready data (what ``SmoothResult.save`` writes)."""
        return {"budget": self.budget, "method": self.method, "kind": self.kind, "bound": self.bound,
                "allotted": self.allotted, "allocation": np.asarray(self.allocation).tolist(),
                "levels": np.asarray(self.levels).tolist(), "hazard_names": list(self.hazard_names)}

    @classmethod
    def from_dict(cls, d: dict) -> "RiskAllocation":
        """The allocation written by :meth:`to_dict`."""
        return cls(float(d["budget"]), np.asarray(d["allocation"], float), np.asarray(d["levels"], float),
                   float(d["bound"]), str(d["method"]), str(d.get("kind", "steps")),
                   tuple(d.get("hazard_names", ())))
