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
  symbolic model (:mod:`belief_nlp.model.doc`, :mod:`belief_nlp.model.nlp_form`);
  the NLP uses g exactly, the CCP step's SDP the piecewise-linear upper bound
  of :func:`tail_pieces` (chords of g through knots whose tail values are a
  fixed ratio apart, plus the constant g(tau_hi)), so every CCP iterate is
  certified and the step stays DPP.
* ``allocation="uniform"``: every pair at tau = g^-1(Delta / (K J)), the
  paper's fixed-level problem at that level.

The target containment keeps the scenario's own confidence (it is not a
collision). The reported bound is never the model's: it is recomputed from
the answer's certified clearances (:func:`belief_nlp.risk.path_risk`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from .errors import ValidationError

__all__ = ["RiskBudget", "RiskAllocation", "tail", "level_for", "tail_pieces", "ALLOCATIONS", "RISK_KINDS"]

ALLOCATIONS = ("optimal", "uniform")
RISK_KINDS = ("steps",)
# Ratio of consecutive knots' tail values in the SDP's bound: the chord of
# g between two such knots lies at most ~3 % above g (measured by
# tests/test_allocation.py).
KNOT_RATIO = 1.5
# Smallest tail value a pair is modelled with, relative to Delta / (K J): below
# it the bound is the constant g(tau_hi) (a pair far from every hazard).
FLOOR = 1e-3


def tail(tau: np.ndarray | float) -> np.ndarray:
    """g(tau) = Phi_bar(sqrt(tau)): the instantaneous collision bound of a pair
    certified at level tau (1 for tau <= 0)."""
    tau = np.asarray(tau, dtype=float)
    return np.where(tau > 0, ndtr(-np.sqrt(np.maximum(tau, 0.0))), 1.0)


def level_for(p: np.ndarray | float) -> np.ndarray:
    """g^-1(p): the level tau whose tail is p (0 < p < 1/2)."""
    p = np.asarray(p, dtype=float)
    return ndtri(p) ** 2


def tail_pieces(budget: float, n_pairs: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A convex piecewise-linear upper bound of g on [tau_lo, inf).

    Returns (slope, intercept, tau_lo, tau_hi): g(tau) <= max_i(slope_i tau +
    intercept_i) for every tau >= tau_lo = g^-1(budget). The pieces are the
    chords of g between knots tau_lo < ... < tau_hi whose tail values fall by
    :data:`KNOT_RATIO` (an upper bound between its knots since g is convex),
    and the constant g(tau_hi) (an upper bound beyond tau_hi since g
    decreases), tau_hi = g^-1(FLOOR budget / n_pairs)."""
    p_hi = budget
    p_lo = FLOOR * budget / max(n_pairs, 1)
    n = max(2, int(math.ceil(math.log(p_hi / p_lo) / math.log(KNOT_RATIO))) + 1)
    p = np.geomspace(p_hi, p_lo, n)
    tau = level_for(p)
    p = tail(tau)                                  # exact values at the knots
    slope = np.diff(p) / np.diff(tau)
    intercept = p[:-1] - slope * tau[:-1]
    return (np.append(slope, 0.0), np.append(intercept, p[-1]), float(tau[0]), float(tau[-1]))


def pwl_tail(tau: np.ndarray, budget: float, n_pairs: int) -> np.ndarray:
    """The bound of :func:`tail_pieces` evaluated at ``tau`` (>= g(tau))."""
    a, c, _, _ = tail_pieces(budget, n_pairs)
    tau = np.asarray(tau, dtype=float)
    return np.max(a * tau[..., None] + c, axis=-1)


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
    kind : {"steps"}
        What the budget bounds: "steps", the probability of being inside some
        hazard at the K + 1 step times (``RiskBound.step_time``). The
        continuous-time bound is reported beside it, not yet budgeted.
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
            raise ValidationError("risk_kind", f"must be one of {RISK_KINDS} (the continuous-time bound is "
                                               f"reported, not yet budgeted), got {self.kind!r:.40}")
        object.__setattr__(self, "kind", self.kind.lower())

    def uniform_level(self, n_pairs: int) -> float:
        """tau of the uniform allocation: g(tau) = budget / n_pairs."""
        return float(level_for(self.budget / n_pairs))

    def warm_level(self, n_pairs: int) -> float:
        """The level of the warm start of an optimal allocation: uniform at 90 %
        of the budget, so that the SDP's piecewise-linear bound (at most ~3 %
        above g) and the floor pieces still fit in the budget."""
        return float(level_for(0.9 * self.budget / n_pairs))


@dataclass(eq=False)
class RiskAllocation:
    """How a smoothed path spends its collision-probability budget.

    Attributes
    ----------
    budget : float
        Delta, the end-to-end budget.
    allocation : ndarray, shape (K, J)
        Risk allotted to each transition-hazard pair: g(levels).
    levels : ndarray, shape (K, J)
        Each pair's confidence level tau_kj (squared Mahalanobis radius).
    bound : float
        The certified end-to-end bound of the returned path: the Boole sum
        of g(clearance) over its pairs, recomputed from the path
        (:func:`belief_nlp.risk.path_risk`, ``step_time``), <= budget.
    method : str
        "optimal" or "uniform".
    kind : str
        What the budget bounds ("steps").
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
        return (f"risk budget {self.budget:.3g} ({self.method} allocation, {self.kind}): certified bound "
                f"{self.bound:.3g}, allotted {self.allotted:.3g}")

    def to_dict(self) -> dict:
        return {"budget": self.budget, "method": self.method, "kind": self.kind, "bound": self.bound,
                "allotted": self.allotted, "allocation": np.asarray(self.allocation).tolist(),
                "levels": np.asarray(self.levels).tolist(), "hazard_names": list(self.hazard_names)}

    @classmethod
    def from_dict(cls, d: dict) -> "RiskAllocation":
        return cls(float(d["budget"]), np.asarray(d["allocation"], float), np.asarray(d["levels"], float),
                   float(d["bound"]), str(d["method"]), str(d.get("kind", "steps")),
                   tuple(d.get("hazard_names", ())))
