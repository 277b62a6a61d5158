"""End-to-end collision-probability bounds of a belief path (issue 20, item 1).

The paper fixes one confidence level chi2 for every transition and hazard;
safety requirements are written end to end. For a path whose pair (k, j)
(transition k, hazard j) has certified clearance m_kj -- a rigorous lower
bound on min over s in [0, 1] of the squared Mahalanobis distance from the
mean x(s) to hazard j under P(s) = P_{k-1} + s W_k (Theorem 1) -- two bounds
follow, both under the paper's model (the robot's state during transition k
is x(s) + noise, X(s) = X_{k-1} + s dx_k + W_k^(1/2) B(s), X_{k-1} ~
N(x_{k-1}, P_{k-1}), B a standard Brownian motion):

* **instantaneous / step-time** (``pairs``, ``step_time``): at any instant s
  of transition k, P(X(s) in hazard j) <= Phi_bar(sqrt(m_kj)) (the hazard
  lies beyond a hyperplane at Mahalanobis distance sqrt(m_kj); one-dimensional
  tail). Boole's inequality over all pairs bounds the probability that the
  robot is inside some hazard at one of the K + 1 step times.
* **continuous-time** (``continuous_pairs``, ``continuous``): with the pair's
  Theorem-1 certificate lam (one for the whole transition), hazard j lies in
  {y : v^T y <= e}, v = A_j^T lam, e = b_j^T lam, so a collision at some s needs
  the 1-D Brownian motion with drift Y(s) = v^T X(s) to cross e. The
  reflection principle gives the crossing probability for a fixed start,
  integrated here over the Gaussian start (Patil and Tanaka 2022); Boole
  over all pairs bounds the probability of touching any hazard at any
  instant of the path. The start includes what the belief model leaves out
  between steps: under feedback on the estimate (the system
  :func:`belief_nlp.study.simulate` runs), the estimate at t_{k-1} is off the
  planned mean by D ~ N(0, P_prior_{k-1} - P_{k-1}), which the control
  removes over the transition (:func:`crossing_probability`); at the step
  times themselves the state is N(x_k, P_prior_k), as in the belief model.

Not bounded: how the estimate itself wanders (the planned means are taken
as what the robot's controller tracks), collisions of a robot of non-zero
size (hazards are inflated beforehand, if at all), and missing the target.
Both numbers are exact to their formulas; ``lam`` and ``clearance`` are
reported so that anyone can recompute them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.special import log_ndtr, ndtr

from .geometry import PolytopeSet, transition_minimiser
from .geometry.bounds import certificate_lower

__all__ = ["RiskBound", "path_risk", "gaussian_tail", "crossing_probability", "continuous_surrogate",
           "surrogate_clearance", "surrogate_covariances", "RISK_STATEMENT"]

RISK_STATEMENT = (
    "step_time bounds the probability that the robot is inside some hazard at one of the K + 1 step times "
    "(per pair: at any instant of the transition, for a belief whose mean is on plan); continuous bounds the "
    "probability of touching some hazard at any instant of the path, with feedback on the Kalman estimate "
    "(Brownian noise between steps); both by Boole's inequality over transition-hazard pairs; not bounded: "
    "model error (other noise or dynamics), robot size, missing the target")

# Gauss-Hermite (probabilists') nodes for the expectation over the estimate's offset
_GH_D, _GH_DW = np.polynomial.hermite_e.hermegauss(16)
_GH_DW = _GH_DW / np.sqrt(2.0 * np.pi)
# cells of a standard normal for upper Riemann sums: (-inf, -10], 800 cells to 10, (10, inf)
_E_EDGES = np.concatenate([[-np.inf], np.linspace(-10.0, 10.0, 801), [np.inf]])
_E_LEFT = np.concatenate([[-np.inf], _E_EDGES[1:-1]])                    # lower end of each cell
_E_MASS = np.diff(ndtr(_E_EDGES))


def gaussian_tail(m: np.ndarray) -> np.ndarray:
    """Phi_bar(sqrt(m)) = P(N(0, 1) > sqrt(m)): the probability mass of a
    Gaussian beyond a hyperplane at squared Mahalanobis distance m. A
    clearance bound m <= 0 claims nothing (the mean may be inside): 1."""
    m = np.asarray(m, dtype=float)
    return np.where(m > 0, ndtr(-np.sqrt(np.maximum(m, 0.0))), 1.0)


def _crossing_fixed_start(h: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """P(min over s in [0, 1] of h + mu s + sigma B(s) <= 0) (reflection
    principle for Brownian motion with drift; 1 for h <= 0)."""
    h, mu, sigma = np.broadcast_arrays(*(np.asarray(a, float) for a in (h, mu, sigma)))
    hp = np.maximum(h, 0.0)
    first = ndtr((-hp - mu) / sigma)
    # exp(-2 mu h / sigma^2) Phi((-h + mu) / sigma), in logs: the factor overflows when mu << 0
    second = np.exp(np.minimum(-2.0 * mu * hp / sigma**2 + log_ndtr((-hp + mu) / sigma), 0.0))
    return np.where(h > 0, np.minimum(first + second, 1.0), 1.0)


def crossing_probability(m0: np.ndarray, v0: np.ndarray, mu: np.ndarray, s2: np.ndarray, e: np.ndarray,
                         vd: np.ndarray | float = 0.0) -> np.ndarray:
    """P(Y(s) <= e for some s in [0, 1]), arrays broadcast, for

        Y(s) = m0 + E + (1 - s) D + s mu + sqrt(s2) B(s),  E ~ N(0, v0), D ~ N(0, vd),

    E, D, B independent: the estimation error E, the estimate's offset D from
    the planned mean (which the feedback removes over the transition) and the
    Brownian motion B. Given (E, D) this is Brownian motion with drift
    mu - D from m0 + E + D, whose crossing probability is the reflection
    formula, decreasing in the start. The expectation over E is an upper
    Riemann sum (each of 800 cells of E, and the tails beyond 10 standard
    deviations, weighted by its exact normal mass and valued at its lower
    end: an upper bound, whatever the tails' size); over D, 16-node
    Gauss-Hermite. With vd = 0 it is the paper's belief model, Y(0) ~ N(m0, v0)."""
    m0, v0, mu, s2, e, vd = (np.asarray(a, float) for a in np.broadcast_arrays(m0, v0, mu, s2, e, vd))
    out = np.empty(m0.shape)
    fixed = vd <= 0                                   # no offset: one node instead of 16 (most pairs)
    for sel, nodes, weights in ((fixed, np.zeros(1), np.ones(1)), (~fixed, _GH_D, _GH_DW)):
        if not np.any(sel):
            continue
        sd0 = np.sqrt(np.maximum(v0[sel], 0.0))[:, None, None]
        D = np.sqrt(np.maximum(vd[sel], 0.0))[:, None, None] * nodes[:, None]      # (n, nD, 1)
        with np.errstate(invalid="ignore"):                                          # 0 * -inf: the lowest cell
            h = np.nan_to_num((m0 - e)[sel][:, None, None] + D + sd0 * _E_LEFT, nan=-np.inf)
        p = _crossing_fixed_start(h, mu[sel][:, None, None] - D, np.sqrt(s2[sel])[:, None, None])
        out[sel] = np.einsum("nij,i,j->n", p, weights, _E_MASS)
    return np.clip(out, 0.0, 1.0)


@dataclass(eq=False)
class RiskBound:
    """Certified end-to-end collision-probability bounds of one path (module doc).

    Attributes
    ----------
    clearance : ndarray, shape (K, J)
        Rigorous lower bound on min over s of the squared Mahalanobis distance
        of each transition/hazard pair (Theorem-1 certificate values).
    pairs : ndarray, shape (K, J)
        Phi_bar(sqrt(clearance)): the instantaneous bound per pair.
    hazard_names : list of str
        Names of the J hazards.
    continuous_pairs : ndarray, shape (K, J)
        The continuous-time (first-passage) bound per pair; computed on
        first use (~0.5 s at K = 20, J = 10).
    lam : ndarray, shape (K, J, F)
        The certificates (1/m) whose hyperplanes the continuous bounds use.
    """

    clearance: np.ndarray
    pairs: np.ndarray
    hazard_names: list
    _inputs: tuple = field(repr=False, default=())

    @cached_property
    def _continuous(self) -> tuple[np.ndarray, np.ndarray]:
        x, P, W, Pd, A, b, cands = self._inputs
        cont, lam = None, None
        for cand in cands:                       # every candidate is rigorous: keep the smaller bound per pair
            c = _continuous_bounds(x, P, W, Pd, A, b, cand)
            if cont is None:
                cont, lam = c, cand.copy()
            else:
                take = c < cont
                cont, lam = np.where(take, c, cont), np.where(take[..., None], cand, lam)
        return cont, lam

    @property
    def continuous_pairs(self) -> np.ndarray:
        """(K, J) continuous-time bound per pair (module doc)."""
        return self._continuous[0]

    @property
    def lam(self) -> np.ndarray:
        """(K, J, F) the certificates whose hyperplanes ``continuous_pairs`` use."""
        return self._continuous[1]

    @property
    def step_time(self) -> float:
        """Boole sum of the instantaneous bounds (capped at 1): the certified
        bound on a collision at one of the step times."""
        return float(min(1.0, np.sum(self.pairs)))

    @property
    def continuous(self) -> float:
        """Boole sum of the continuous-time bounds (capped at 1)."""
        return float(min(1.0, np.sum(self.continuous_pairs)))

    @property
    def statement(self) -> str:
        """What the two numbers bound, and what they do not."""
        return RISK_STATEMENT

    def per_transition(self, continuous: bool = False) -> np.ndarray:
        """(K,) the bound allotted to each transition (sum over hazards)."""
        return np.sum(self.continuous_pairs if continuous else self.pairs, axis=1)

    def summary(self) -> str:
        """One line: both bounds and the pair that carries most of them."""
        k, j = np.unravel_index(int(np.argmax(self.pairs)), self.pairs.shape)
        return (f"collision risk <= {self.step_time:.3g} at the step times, <= {self.continuous:.3g} in continuous "
                f"time (largest pair: transition {k + 1}, {self.hazard_names[j]}, {self.pairs[k, j]:.3g})")

    def to_dict(self) -> dict:
        """JSON-ready: both totals, the per-pair arrays and the statement."""
        return {"step_time": self.step_time, "continuous": self.continuous, "statement": self.statement,
                "pairs": self.pairs.tolist(), "continuous_pairs": self.continuous_pairs.tolist(),
                "clearance": self.clearance.tolist(), "hazard_names": list(self.hazard_names)}


def path_risk(scenario, path, certificates: np.ndarray | None = None) -> RiskBound:
    """The certified risk bounds of ``path`` (a BeliefPath) in ``scenario``.

    Parameters
    ----------
    scenario : Scenario
        Its hazards (obstacles, then domain walls) are the pairs' hazards.
    path : BeliefPath
        Means, posterior covariances and the noise of each transition.
    certificates : ndarray, shape (K, J, F), optional
        Theorem-1 certificates in 1/m (``SmoothResult.certificates``); each
        pair uses whichever of them and the exact minimiser's certificate
        gives the larger clearance and, separately, the smaller
        continuous-time bound (both are rigorous).

    Returns
    -------
    RiskBound
    """
    x, P, W = path.x, path.P, path.transition_noise
    hz = scenario.hazards
    tm = transition_minimiser(x[:-1], P[:-1], x[1:], W, PolytopeSet.cached(hz), want_lam=True)
    F = tm.lam.shape[-1]
    A = np.zeros((len(hz), F, path.dim))
    b = np.ones((len(hz), F))                                   # padded faces: a zero row with b = 1 (inert)
    for j, h in enumerate(hz):
        A[j, :h.n_faces], b[j, :h.n_faces] = h.A, h.b
    cands = [np.maximum(np.nan_to_num(tm.lam), 0.0)]
    # the estimate's offset from the planned mean at the start of each transition: covariance
    # P_prior - P of the step before (0 at the start: the estimate starts at x0)
    Pd = np.concatenate([np.zeros((1, path.dim, path.dim)), path.P_prior[1:-1] - P[1:-1]])
    clearance = tm.lower
    if certificates is not None:
        cert = np.zeros_like(cands[0])
        given = np.maximum(np.nan_to_num(np.asarray(certificates, float)), 0.0)
        cert[..., :min(F, given.shape[-1])] = given[..., :F]
        clearance = np.maximum(clearance, certificate_lower(A, b, x[:-1], P[:-1], x[1:], W, cert))
        cands.append(cert)
    return RiskBound(clearance, gaussian_tail(clearance), [h.name for h in hz], (x, P, W, Pd, A, b, cands))


def surrogate_covariances(P: np.ndarray, P_prior: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Sigma_k = P_prior_{k-1} + W_k for k = 1..K, (K, d, d), with P_prior_0 = P_0
    (the estimate starts at x0): the covariance under which the continuous-time
    surrogate asks each pair's level at both ends of transition k
    (:func:`continuous_surrogate`). ``P``, ``P_prior``: (K+1, d, d); ``W``: (K, d, d)."""
    start = np.concatenate([P[:1], P_prior[1:-1]])
    return start + W


def surrogate_clearance(scenario, path) -> np.ndarray:
    """(K, J) certified squared Mahalanobis distance of each hazard from the
    segment [x_{k-1}, x_k] under Sigma_k (:func:`surrogate_covariances`): the
    clearance the continuous-time surrogate asks each pair's level of."""
    from .geometry import PolytopeSet

    Sig = surrogate_covariances(path.P, path.P_prior, path.transition_noise)
    tm = transition_minimiser(path.x[:-1], Sig, path.x[1:], np.zeros_like(Sig),
                              PolytopeSet.cached(scenario.hazards))
    return tm.lower


def continuous_surrogate(scenario, path, factor: float = 3.0) -> np.ndarray:
    """(K, J) per-pair upper bounds on the continuous-time crossing probability
    (:func:`crossing_probability`, with the estimate's offset): ``factor``
    g(m_kj), m_kj = :func:`surrogate_clearance`.

    Why (docs/safety.md, "The continuous-time surrogate"): with the hyperplane
    v^T y = e of the pair's certificate, the crossing variable of
    :func:`crossing_probability` satisfies
    min_s Y(s) - e >= M + E + min(D, 0) - sqrt(s2) |G| (M = min(m0, m0 + mu) - e,
    G standard normal: the minimum of a Brownian motion on [0, 1]); splitting on
    the signs of D and G gives P <= Phi_bar(M / sd1) + 2 Phi_bar(M / sd) <=
    3 Phi_bar(M / sd), sd1^2 = v0 + s2, sd^2 = v0 + vd + s2 = v^T Sigma_k v; and
    M / sd >= sqrt(m_kj) for the hyperplane that separates the hazard from the
    segment best. The model's continuous budget asks sum_kj g(tau_kj) <=
    Delta / 3 with every pair's clearance under Sigma_k at least tau_kj."""
    return np.minimum(factor * gaussian_tail(surrogate_clearance(scenario, path)), 1.0)


def _continuous_bounds(x, P, W, Pd, A, b, lam) -> np.ndarray:
    """For certificates lam (K, J, F): the continuous-time crossing bound of
    the hyperplane v^T y <= e (v = A^T lam, e = b^T lam) per pair; 1 where
    lam = 0 (no hyperplane)."""
    v = np.einsum("jfd,kjf->kjd", A, lam)                       # (K, J, d)
    e = np.einsum("jf,kjf->kj", b, lam)
    q0 = np.einsum("kjd,kde,kje->kj", v, P[:-1], v)
    qd = np.einsum("kjd,kde,kje->kj", v, Pd, v)                 # the estimate's offset (feedback model)
    s2 = np.einsum("kjd,kde,kje->kj", v, W, v)
    m0 = np.einsum("kjd,kd->kj", v, x[:-1])
    mu = np.einsum("kjd,kd->kj", v, x[1:]) - m0
    ok = (s2 > 0) & np.any(lam > 0, axis=-1)
    pc = np.ones_like(e)
    pc[ok] = crossing_probability(m0[ok], q0[ok], mu[ok], s2[ok], e[ok], np.maximum(qd[ok], 0.0))
    return pc
