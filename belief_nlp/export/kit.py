"""The belief-space MPC layout that every adapter installs (scaled units).

One stage of a receding-horizon belief MPC on a single integrator:

* state ``s = (x', vech P')`` -- the mean and the posterior covariance in the
  model's scaled units (x' = x / sigma, P' = P / sigma^2; vech = the lower
  triangle, column by column);
* input ``v = (u', l, lam'[, slack])`` -- the step u' = x'_{k+1} - x'_k, the
  sensing factor l (lower triangle of L, S' = L L^T = sigma^2 S, PSD by
  construction), the certificates lam' = sigma lam of the stage bundle and,
  for soft variants, the slacks;
* dynamics ``s_{k+1} = step(s_k, v_k)``: x' + u' and the Kalman recursion
  P' <- update_cov(predict(P', W'), S') of :mod:`belief_nlp.model.terms`;
* constraints ``rows(s_k, v_k, gate_k, p, p_t)`` with bounds ``lbg``/``ubg``:
  the stage bundle of the transition (x'_k, P'_k) -> x'_{k+1}, then the
  terminal bundle of the next belief. ``gate_k = (active, final)``: final = 1
  switches the terminal rows on at the stage whose next belief is the last
  one of the run; active = 0 switches off a stage past the end of the run
  (a fixed-horizon tool predicts beyond it; those stages are never applied).
  A switched-off row reads ``(1 - on) * nominal + on * row``, so it is
  always satisfied and the function stays smooth;
* stage cost ``cost(s_k, v_k, r_k)`` in SI units: ||x_{k+1} - x_k||^2 (m^2) +
  alpha * information (nats) + track * ||x_{k+1} - r_{k+1}||^2 + a small
  proximal term ridge * ||lam' - lam'_ref||^2 toward the previous plan's
  certificates (their optimal set is flat in some directions; the
  smoother's IPOPT method does the same, docs/numerics.md) + prox *
  ||(u', l) - (u', l)_ref||^2 toward the previous plan's steps and sensing
  (default 0; it convexifies the bilinear certificate rows, see docs/mpc.md)
  + the soft penalties, times ``active``.

All of these are SX ``casadi.Function`` objects, so a do-mpc or acados model
inlines them and Opti/rockit call them (use ``expand=True``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .. import belief
from ..errors import ValidationError
from ..model import terms
from ..path import BeliefPath
from ..scenario import Scenario
from .bundle import SafetyBundle, TerminalBundle, _scenario, stage_bundle, terminal_bundle
from .certificates import certificate_warm_start

__all__ = ["BeliefMPC", "reference_path"]


def reference_path(scenario: Scenario | str, steps: int | None, seed: int = 0, n_nodes: int = 300) -> BeliefPath:
    """A safe reference of ``steps`` transitions: an IG-RRT* plan (per-step
    noise) made feasible by :func:`belief_nlp.warm_start` (sensing added).
    ``steps`` None: the scenario's K (else 20), or the plan's edge count
    when that is larger (every vertex is kept). Raises SolverError when the
    plan fails or has more edges than ``steps``."""
    from ..errors import SolverError
    from ..planner import plan
    from ..smoother.warmstart import warm_start

    sc = _scenario(scenario)
    res = plan(sc, n_nodes=n_nodes, seed=seed, noise="per_step", max_radius=1.5)
    if not res.success:
        raise SolverError(f"no reference path: planning failed ({res.message})")
    edges = res.path.K
    if steps is None:
        steps = max(int(sc.K or 20), edges)
    elif edges > steps:
        # a plan's vertices are where it turns around obstacles: none may be dropped
        raise SolverError(f"the reference plan (seed {seed}) has {edges} edges, more than steps = {steps}: give "
                          f"steps >= {edges}, or None for as many as the plan needs")
    return warm_start(sc, res.path, K=steps).path


@dataclass
class BeliefMPC:
    """Functions, sizes and conversions of the MPC layout (module doc).

    Build with :meth:`build`. ``stage`` and ``terminal`` are the scaled
    bundles; ``step``, ``rows`` and ``cost`` the stage functions; ``lbg`` and
    ``ubg`` the bounds of ``rows``; ``sigma`` the scale (m).
    """

    scenario: Scenario
    stage: SafetyBundle
    terminal: TerminalBundle
    alpha: float
    track: float
    ridge: float
    prox: float = 0.0
    step: ca.Function = field(init=False)
    rows: ca.Function = field(init=False)
    cost: ca.Function = field(init=False)
    _rollouts: dict = field(init=False, default_factory=dict, repr=False)
    _hazards: object = field(init=False, default=None, repr=False)

    @classmethod
    def build(cls, scenario: Scenario | str, alpha: float | None = None, track: float = 10.0,
              soft: tuple[float, str] | None = None, margin: float | None = None,
              ridge: float = 1e-4, prox: float = 0.0) -> "BeliefMPC":
        """The layout for ``scenario``; ``soft=(weight, "l1"|"l2")`` softens the
        margin and target rows; ``margin`` as in :func:`.stage_bundle`;
        ``ridge`` and ``prox`` weight the proximal terms toward the previous
        plan's certificates and steps/sensing (module doc)."""
        sc = _scenario(scenario)
        st = stage_bundle(sc, scaled=True, margin=margin, soft=soft)
        te = terminal_bundle(sc, scaled=True, soft=soft)
        alpha = float(sc.alpha if alpha is None else alpha)
        if not np.isfinite(alpha) or alpha < 0 or not np.isfinite(track) or track < 0:
            raise ValidationError("alpha", f"alpha and track must be finite and >= 0, got {alpha!r}, {track!r}")
        return cls(sc, st, te, alpha, float(track), float(ridge), float(prox))

    def __post_init__(self) -> None:
        d = self.d
        s, v = ca.SX.sym("s", self.nx), ca.SX.sym("v", self.nu)
        gate, ref = ca.SX.sym("gate", 2), ca.SX.sym("ref", self.n_ref)
        on, fin = gate[0], gate[0] * gate[1]
        p, pt = ca.SX.sym("p", self.stage.function.size1_in("p")), ca.SX.sym("p_t", self.terminal.function.size1_in("p"))
        x, P = self.unpack_state(s)
        u, lv, lam, sl, slt = self.unpack_input(v)
        x1, P1 = x + u, terms.update_cov(terms.predict(P, self.W), self.sensing(lv))
        self.step = ca.Function("belief_step", [s, v], [ca.vertcat(x1, self.vech(P1))], ["s", "v"], ["s_next"])
        st = self.stage(x, P, x1, self.W, lam, p, slack=sl if self.stage.n_slack else None)
        te = self.terminal(x1, P1, pt, slack=slt if self.terminal.n_slack else None)
        g_st, pen = (st[0], st[1]) if self.stage.n_slack else (st, 0)
        g_te, pen_t = (te[0], te[1]) if self.terminal.n_slack else (te, 0)
        g_st = on * g_st + (1 - on) * np.maximum(self.stage.nominal, self.stage.lbg)
        g_te = fin * g_te + (1 - fin) * self.terminal.nominal
        self.rows = ca.Function("belief_rows", [s, v, gate, p, pt], [ca.vertcat(g_st, g_te)],
                                ["s", "v", "gate", "p", "p_t"], ["g"])
        sig2 = self.sigma ** 2
        ru, rl, rlam, _, _ = self.unpack_input(ref[d:])      # the previous plan's input
        ell = (sig2 * terms.control(x, x1) + self.alpha * terms.information_cov(terms.predict(P, self.W),
                                                                               self.sensing(lv))
               + self.track * sig2 * ca.sumsqr(x1 - ref[:d]) + self.ridge * ca.sumsqr(lam - rlam)
               + self.prox * ca.sumsqr(ca.vertcat(u - ru, lv - rl)) + pen + gate[1] * pen_t)
        ell = on * ell + (1 - on) * self.ridge * ca.sumsqr(v)     # past the end: keep the stage well posed
        self.cost = ca.Function("belief_stage_cost", [s, v, gate, ref], [ell], ["s", "v", "gate", "ref"], ["cost"])

    # ------------------------------------------------------------- sizes
    @property
    def d(self) -> int:
        """Dimension of the space (2 or 3)."""
        return self.stage.d

    @property
    def sigma(self) -> float:
        """The length scale (m) of the model's scaled units: sqrt of the largest eigenvalue of W."""
        return self.stage.sigma

    @property
    def W(self) -> np.ndarray:
        """Process noise per step in scaled units, ``scenario.W / sigma**2``, shape (d, d)."""
        return np.asarray(self.scenario.W, float) / self.sigma ** 2

    @property
    def tri(self) -> list[tuple[int, int]]:
        """Lower-triangle indices (i, j), column by column."""
        return [(i, j) for j in range(self.d) for i in range(j, self.d)]

    @property
    def n_ref(self) -> int:
        """Size of the cost's ``ref`` input: next reference mean (d) and the previous plan's input (nu)."""
        return self.d + self.nu

    @property
    def nx(self) -> int:
        """Size of the state vector ``(x', vech P')`` (scaled units)."""
        return self.d + len(self.tri)

    @property
    def nu(self) -> int:
        """Size of the input vector ``(u', l, lam', stage slack, terminal slack)``."""
        return self.d + len(self.tri) + self.stage.n_lam + self.stage.n_slack + self.terminal.n_slack

    @property
    def lbg(self) -> np.ndarray:
        """Lower bounds of the stage rows then the terminal rows (what :attr:`rows` returns)."""
        return np.concatenate([self.stage.lbg, self.terminal.lbg])

    @property
    def ubg(self) -> np.ndarray:
        """Upper bounds of the stage rows then the terminal rows."""
        return np.concatenate([self.stage.ubg, self.terminal.ubg])

    @property
    def row_names(self) -> tuple[str, ...]:
        """Names of the rows, stage bundle first, in the order of :attr:`lbg`."""
        return self.stage.names + self.terminal.names

    # ---------------------------------------------------- packing helpers
    def vech(self, M):
        """The lower triangle of a symmetric CasADi matrix ``M`` as a column, column by column."""
        return ca.vertcat(*[M[i, j] for i, j in self.tri])

    def unvech(self, v):
        """The symmetric (d, d) CasADi matrix whose lower triangle is ``v`` (inverse of :meth:`vech`)."""
        M = ca.SX.zeros(self.d, self.d) if isinstance(v, ca.SX) else ca.MX.zeros(self.d, self.d)
        for n, (i, j) in enumerate(self.tri):
            M[i, j] = v[n]
            M[j, i] = v[n]
        return M

    def unpack_state(self, s):
        """``(x, P)`` views of a state vector ``s = (x', vech P')``."""
        return s[:self.d], self.unvech(s[self.d:])

    def unpack_input(self, v):
        """(u', l, lam', stage slack, terminal slack) views of an input vector."""
        n = [self.d, len(self.tri), self.stage.n_lam, self.stage.n_slack, self.terminal.n_slack]
        cut = np.cumsum([0] + n)
        return tuple(v[cut[i]:cut[i + 1]] for i in range(5))

    def sensing(self, lv):
        """S' = L L^T from the lower-triangle entries l (PSD by construction)."""
        L = ca.SX.zeros(self.d, self.d) if isinstance(lv, ca.SX) else ca.MX.zeros(self.d, self.d)
        for n, (i, j) in enumerate(self.tri):
            L[i, j] = lv[n]
        return ca.mtimes(L, L.T)

    def state(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The state vector of an SI belief (x [m], P [m^2])."""
        Ps = np.asarray(P, float) / self.sigma ** 2
        return np.concatenate([np.asarray(x, float) / self.sigma, [Ps[i, j] for i, j in self.tri]])

    def input(self, x: np.ndarray, x_next: np.ndarray, S: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The input vector of an SI step (x -> x_next [m], sensing S [1/m^2]) with
        scaled certificates ``lam`` (J F); slacks zero."""
        from ..model.nlp_matrices import _psd_factor

        L = _psd_factor(np.asarray(S, float) * self.sigma ** 2)
        return np.concatenate([(np.asarray(x_next) - np.asarray(x)) / self.sigma, [L[i, j] for i, j in self.tri],
                               lam, np.zeros(self.stage.n_slack + self.terminal.n_slack)])

    def apply(self, x: np.ndarray, P: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apply an input to an SI belief: (x_next [m], P_next [m^2], S [1/m^2]),
        the posterior from :mod:`belief_nlp.belief` (the plant, not the model)."""
        u, lv = np.asarray(v[:self.d], float), np.asarray(v[self.d:self.d + len(self.tri)], float)
        L = np.zeros((self.d, self.d))
        for n, (i, j) in enumerate(self.tri):
            L[i, j] = lv[n]
        S = L @ L.T / self.sigma ** 2
        S = 0.5 * (S + S.T)
        P_next = belief.update(belief.predict(P, self.scenario.W), S)
        return np.asarray(x, float) + self.sigma * u, 0.5 * (P_next + P_next.T), S

    @staticmethod
    def gates(t: int, horizon: int, steps: int) -> np.ndarray:
        """(2, horizon) gate values of the solve at time t of a run of ``steps``."""
        k = t + np.arange(horizon)
        return np.stack([(k < steps).astype(float), (k == steps - 1).astype(float)])

    @property
    def hazards(self):
        """The scenario's hazards as a :class:`~belief_nlp.geometry.PolytopeSet`
        (built once: :meth:`hold` runs every closed-loop step)."""
        if getattr(self, "_hazards", None) is None:
            from ..geometry import PolytopeSet

            self._hazards = PolytopeSet.build(self.scenario.hazards)
        return self._hazards

    def guess(self, reference: BeliefPath, extra: int = 0, levels: np.ndarray | None = None) -> np.ndarray:
        """Inputs (nu, K + extra) that reproduce ``reference`` (a safe path) with
        certificates from :func:`.certificate_warm_start` (at ``levels`` (K, J)
        when given), so that the first solve starts feasible; ``extra`` stages
        past the end (switched off by :meth:`gates`) stay put with a tiny sensing factor."""
        lam = certificate_warm_start(self.scenario, reference, self.stage, hazards=self.hazards, levels=levels)
        U = [self.input(reference.x[k], reference.x[k + 1], reference.S[k + 1], lam[k]) for k in range(reference.K)]
        rest = self.input(reference.x[-1], reference.x[-1], np.zeros((self.d, self.d)), np.zeros(self.stage.n_lam))
        return np.stack(U + [rest] * extra, 1)

    def rollout(self, state: np.ndarray, V: np.ndarray) -> np.ndarray:
        """States (nx, N+1) of the inputs V (nu, N) from ``state`` (the model's :attr:`step`)."""
        V = np.asarray(V, float)
        state = np.asarray(state, float).reshape(-1, 1)
        if V.shape[1] == 0:
            return state
        n = V.shape[1]
        if n not in self._rollouts:
            self._rollouts[n] = self.step.mapaccum(n)      # one call for the whole horizon
        return np.hstack([state, self._rollouts[n](state, V).full()])

    def hold(self, state: np.ndarray, v_last: np.ndarray) -> np.ndarray:
        """An input for one more stage after a plan that ends in ``state``: stay
        put with the sensing of ``v_last`` and the exact certificates of that
        transition (:func:`.certificate_warm_start`), so that a shifted plan
        plus this stage is a feasible warm start. Returns ``v_last`` itself
        when holding still is not clear."""
        from ..errors import InfeasibleStartError

        state = np.asarray(state, float)
        x, P = state[:self.d] * self.sigma, np.zeros((self.d, self.d))
        for n, (i, j) in enumerate(self.tri):
            P[i, j] = P[j, i] = state[self.d + n] * self.sigma ** 2
        v = np.array(v_last, float)
        v[:self.d] = 0.0
        _, _, S = self.apply(x, P, v)
        try:
            path = BeliefPath.from_sensing(np.array([x, x]), P, S[None], W=self.scenario.W, noise="per_step")
            v[self.d + len(self.tri):self.d + len(self.tri) + self.stage.n_lam] = \
                certificate_warm_start(self.scenario, path, self.stage, hazards=self.hazards)[0]
        except (InfeasibleStartError, ValidationError, ValueError):
            return np.array(v_last, float)
        return v

    def references(self, reference: BeliefPath, guess: np.ndarray, t: int, horizon: int) -> np.ndarray:
        """(n_ref, horizon) ``ref`` values of the solve at time t: the scaled
        reference means of t+1..t+horizon (held at the last one) and the
        inputs ``guess`` (nu, horizon) -- the previous plan, shifted -- for the
        proximal terms."""
        k = np.minimum(t + 1 + np.arange(horizon), reference.K)
        return np.concatenate([reference.x[k].T / self.sigma, np.asarray(guess, float)])
