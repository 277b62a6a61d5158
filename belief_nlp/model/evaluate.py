"""Numbers from the model: the exact DOC program's cost and constraint margins
at a point, and the conversions between points and belief paths.

:class:`BeliefModel` evaluates the terms of :mod:`.terms` (the same CasADi
expressions the solver forms are built from), mapped over steps and hazards.
It also owns the (scenario, K, alpha) data and, lazily, the symbolic convex
form of the CCP step.
"""

from __future__ import annotations

import functools
from functools import cached_property

import casadi as ca
import numpy as np

from ..scenario import Scenario
from . import terms
from .data import Layout, ProblemData, surrogate_information, sym

__all__ = ["BeliefModel"]


def _hcat(M: np.ndarray) -> np.ndarray:
    """(n, r, c) -> r x (n c): the column layout of CasADi's Function.map
    (block i is M[i]; one reshape, not a concatenation of n pieces)."""
    M = np.asarray(M)
    n, r, c = M.shape
    return np.swapaxes(M, 0, 1).reshape(r, n * c)


@functools.lru_cache(maxsize=32)
def _functions(d: int, F: int, chi2: float, chi2_target: float, W: bytes) -> tuple:
    """The model's CasADi functions of :mod:`.terms` and a dict for their
    maps, shared by every model with the same dimensions, levels and W: a
    smoothing call makes two models, and building them took ~4.5 ms each
    (a tenth of a K = 20 re-plan). CasADi functions are immutable."""
    x, xp = ca.SX.sym("x", d), ca.SX.sym("x_prev", d)
    Y, Q, P = ca.SX.sym("Y", d, d), ca.SX.sym("Q", d, d), ca.SX.sym("P", d, d)
    lam, A, b = ca.SX.sym("lam", F), ca.SX.sym("A", F, d), ca.SX.sym("b", F)
    a, bt = ca.SX.sym("a", d), ca.SX.sym("bt")
    Wm = ca.DM(np.frombuffer(W).reshape(d, d))
    return (ca.Function("step_cost", [xp, x, Y, Q], [terms.control(xp, x), terms.information(Y, Q)],
                        ["x_prev", "x", "Y", "Q"], ["control", "information"]),
            ca.Function("margin_inv", [x, Y, lam, A, b], [terms.collision_margin_inv(x, Y, lam, A, b, chi2)],
                        ["x", "Y", "lam", "A", "b"], ["margin"]),
            ca.Function("margin_cov", [x, P, lam, A, b], [terms.collision_margin_cov(x, P, lam, A, b, chi2)],
                        ["x", "P", "lam", "A", "b"], ["margin"]),
            ca.Function("target_margin", [x, Y, a, bt], [terms.target_margin(x, Y, a, bt, chi2_target)],
                        ["x", "Y", "a", "b"], ["margin"]),
            ca.Function("kalman_residual", [Q, Y], [terms.kalman_residual(Q, Y, Wm)], ["Q", "Y_prev"], ["residual"]),
            {})


class BeliefModel:
    """The model of the smoothing problem for one scenario, horizon and alpha.

    With ``risk`` (a :class:`belief_nlp.allocation.RiskBudget`) the collision
    level is the budget's: uniform, every pair at g^-1(Delta / (K J)); optimal,
    each pair's level a variable under the budget (``data.budget``), with the
    uniform level at 90 % of Delta as the model's reference level (the top
    of the warm start's ladder, :mod:`belief_nlp.smoother.budget_start`). A continuous-time
    budget (``risk.kind == "continuous"``) asks each pair's level at both ends
    of its transition under Sigma_k (``data.continuous``,
    :meth:`surrogate_information`) and spends Delta / 3 on the levels.

    Its CasADi functions are built once from :mod:`.terms`; the methods below
    evaluate them on a :class:`Layout` (scaled units).
    """

    def __init__(self, scenario: Scenario, K: int, alpha: float | None = None, risk=None):
        self.scenario = scenario
        self.risk_budget = risk               # a RiskBudget (belief_nlp.allocation) or None
        chi2 = budget = None
        if risk is not None:
            n_pairs = int(K) * len(scenario.hazards)
            if risk.allocation == "uniform":
                chi2 = risk.uniform_level(n_pairs)
            else:
                chi2, budget = risk.warm_level(n_pairs), risk.model_budget
        continuous = risk is not None and risk.kind == "continuous"
        self.data = ProblemData.from_scenario(scenario, K, alpha, chi2=chi2, budget=budget, continuous=continuous)
        D = self.data
        fs = _functions(D.d, D.F, float(D.chi2), float(D.chi2_target), np.ascontiguousarray(D.W, float).tobytes())
        self.f_step, self.f_margin_inv, self.f_margin_cov, self.f_target, self.f_kalman = fs[:5]
        self._maps: dict[tuple[str, int], ca.Function] = fs[5]

    def _map(self, f: ca.Function, n: int) -> ca.Function:
        """``f.map(n)``, built once per function set (a call evaluates the
        model's functions a dozen times, each map was built anew: ~0.1 ms each)."""
        key = (f.name(), n)
        fn = self._maps.get(key)
        if fn is None:
            fn = self._maps[key] = f.map(n)
        return fn

    @cached_property
    def convex_form(self):
        """The symbolic convexified program of a CCP step (:func:`.doc.convex_form`)."""
        from .doc import convex_form

        return convex_form(self.data)

    # ------------------------------------------------------ evaluations
    def cost(self, z: Layout) -> tuple[float, float, float]:
        """(total, control, information) in SI units: sum ||dx||^2 (m^2) and nats."""
        D = self.data
        K = D.K
        c, i = self._map(self.f_step, K)(z.x[:-1].T, z.x[1:].T, _hcat(z.Y[1:]), _hcat(z.Q[1:]))
        control = float(D.sigma**2 * np.sum(c.full()))
        info = float(np.sum(i.full()))
        return control + D.alpha * info, control, info

    def _pairs(self, xs: np.ndarray, Ms: np.ndarray, lam: np.ndarray, f: ca.Function) -> np.ndarray:
        """f over every (step, hazard): xs (n, d), Ms (n, d, d), lam (n, J, F) -> (n, J)."""
        D = self.data
        n, J = xs.shape[0], D.J
        if n == 0:
            return np.zeros((0, J))
        m = n * J
        A = np.tile(D.A, (n, 1, 1))
        out = self._map(f, m)(np.repeat(xs, J, axis=0).T, _hcat(np.repeat(Ms, J, axis=0)), lam.reshape(m, D.F).T,
                       _hcat(A), np.tile(D.b, (n, 1)).T)
        return out.full().reshape(n, J)

    def surrogate_information(self, z: Layout) -> np.ndarray:
        """(K, d, d) Sigma_k^-1 of the continuous-time surrogate, k = 1..K:
        Sigma_k = P_prior_{k-1} + W = Q_{k-1}^-1 + W (k >= 2), Sigma_1 = P0 + W
        (:func:`belief_nlp.risk.surrogate_covariances`)."""
        return surrogate_information(self.data, z.Q)

    def segments(self, z: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The transitions as the exact checks see them, scaled units: means
        x_{k-1} -> x_k and covariance P(s) = C_k + s V_k, (x_prev, C, x_next, V):
        the belief's (P_{k-1}, W), or under the continuous surrogate (Sigma_k, 0)."""
        D = self.data
        if D.continuous:
            Sig = np.linalg.inv(self.surrogate_information(z))
            return z.x[:-1], sym(Sig), z.x[1:], np.zeros_like(Sig)
        P = self.covariances(z)
        return z.x[:-1], P[:-1], z.x[1:], np.broadcast_to(D.W, P[1:].shape).copy()

    def transition_margins(self, z: Layout) -> tuple[np.ndarray, np.ndarray]:
        """Theorem-1 margins (certificate values minus each transition's level,
        as the NLP's rows) of both ends of every transition and hazard, scaled
        units, >= 0 is clear: (start (K, J), end (K, J)). Transition 1's level
        is the start's own (chi2 - relief). Under the continuous surrogate
        both ends use Sigma_k."""
        D = self.data
        if D.continuous:
            T = self.surrogate_information(z)
            start = self._pairs(z.x[:-1], T, z.lam, self.f_margin_inv)
            end = self._pairs(z.x[1:], T, z.lam, self.f_margin_inv)
        else:
            end = self._pairs(z.x[1:], z.Q[1:], z.lam, self.f_margin_inv)
            start = np.empty_like(end)
            start[1:] = self._pairs(z.x[1:-1], z.Y[1:-1], z.lam[1:], self.f_margin_inv)
            start[0] = self._pairs(z.x[:1], D.P0[None], z.lam[:1], self.f_margin_cov)[0]
        if D.relief:
            start[0] += D.relief
            end[0] += D.relief
        return start, end

    def clearances(self, z: Layout) -> np.ndarray:
        """(K, J) certified squared Mahalanobis clearance of every pair: the
        smaller Theorem-1 certificate value of its two ends (a rigorous lower
        bound over the whole transition)."""
        start, end = self.transition_margins(z)
        return np.minimum(start, end) + self.data.collision_levels()

    def risk_sum(self, z: Layout) -> float:
        """sum_kj g(clearance_kj): the certified step-time collision bound of
        ``z`` by its own certificates (:mod:`belief_nlp.allocation`)."""
        from ..allocation import tail

        return float(np.sum(tail(self.clearances(z))))

    def target_margins(self, z: Layout) -> np.ndarray:
        """Containment margin of the final posterior per target face (scaled length)."""
        D = self.data
        N = D.At.shape[0]
        out = self._map(self.f_target, N)(np.tile(z.x[-1][:, None], (1, N)), _hcat(np.repeat(z.Y[-1:], N, axis=0)),
                                   D.At.T, D.bt[None, :])
        return out.full().ravel()

    def kalman_residuals(self, z: Layout) -> np.ndarray:
        """Q_k^-1 - Y_{k-1}^-1 - W for k = 2..K, (K-1, d, d)."""
        K, d = self.data.K, self.data.d
        if K < 2:
            return np.zeros((0, d, d))
        g = self._map(self.f_kalman, K - 1)(_hcat(z.Q[2:]), _hcat(z.Y[1:-1])).full()
        return sym(np.stack(np.split(g, K - 1, axis=1)))

    def kalman_gaps(self, z: Layout) -> np.ndarray:
        """Smallest eigenvalue of each Kalman residual (>= 0: the relaxation holds)."""
        r = self.kalman_residuals(z)
        return np.linalg.eigvalsh(r)[:, 0] if r.shape[0] else np.zeros(0)

    def kalman_relative_gap(self, z: Layout) -> float:
        """max_k ||Q_k^-1 - Y_{k-1}^-1 - W|| / ||Q_k^-1||: how far the relaxed
        Kalman step (prob_2) is from the equality (Lemma 2 says 0 at the optimum)."""
        r = self.kalman_residuals(z)
        if not r.shape[0]:
            return 0.0
        Pq = np.linalg.inv(z.Q[2:])
        return float(np.max(np.linalg.norm(r, axis=(1, 2)) / np.linalg.norm(Pq, axis=(1, 2))))

    # ------------------------------------------------------ conversions
    def covariances(self, z: Layout) -> np.ndarray:
        """Posterior covariances (K+1, d, d) in scaled units: P_0, then Y_k^-1."""
        P = np.empty_like(z.S)
        P[0] = self.data.P0
        P[1:] = sym(np.linalg.inv(z.Y[1:]))
        return P

    def tighten(self, z: Layout) -> Layout:
        """Replace Q by the Kalman recursion from S (Lemma 2): stays feasible
        (every ellipse shrinks) and never increases the cost."""
        D = self.data
        out = z.copy()
        out.Q[1] = D.Q1
        for k in range(2, D.K + 1):
            Pk = np.linalg.inv(out.Q[k - 1] + out.S[k - 1])
            out.Q[k] = sym(np.linalg.inv(Pk + D.W))
        return out

    def to_path(self, z: Layout, meta: dict | None = None):
        """BeliefPath in SI units (Kalman-consistent: priors rolled out from S)."""
        from ..path import BeliefPath

        D = self.data
        S_si = z.S / D.sigma**2
        S_si[0] = 0.0
        return BeliefPath.from_sensing(z.x * D.sigma, self.scenario.P0, S_si, W=self.scenario.W,
                                       noise="per_step", meta=dict(meta or {}))

    def from_path(self, path, lam_si: np.ndarray) -> Layout:
        """Layout from a per-step BeliefPath (SI) and its certificates (K, J, F) in SI."""
        D = self.data
        s2 = D.sigma**2
        S = np.array(path.S, dtype=float) * s2
        S[0] = 0.0
        Q = np.zeros_like(S)
        Q[1:] = np.linalg.inv(np.asarray(path.P_prior[1:]) / s2)
        return Layout(np.array(path.x, dtype=float) / D.sigma, sym(Q), sym(S), np.asarray(lam_si) * D.sigma)
