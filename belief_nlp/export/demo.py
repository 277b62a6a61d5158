"""The first receding-horizon demo: ``mpc_demo`` in ``casadi.Opti`` on a
corridor with one obstacle, built from the per-hazard functions of
:mod:`.functions` (kept for the notebook and its users; the closed loops of
:mod:`.closed_loop` use the stacked bundles)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SolverError, ValidationError
from ..path import BeliefPath
from ..scenario import Scenario, load_scenario, scenario_from_dict
from .functions import _slug, export_functions

__all__ = ["demo_scenario", "mpc_demo"]


def demo_scenario() -> Scenario:
    """A 1 m x 0.5 m corridor with one box obstacle in the middle: the robot
    starts at (0.1, 0.2) and must reach a 0.1 m box around (0.9, 0.2), passing
    the obstacle [0.4, 0.6] x [0.1, 0.3] above or below. W = 0.2e-3 I per step
    (as paper-multi), 90 % ellipses."""
    return scenario_from_dict({
        "name": "mpc-demo",
        "description": "One box obstacle in a corridor, for the receding-horizon MPC demo of belief_nlp.export.",
        "confidence": 0.9,
        "alpha": 0.1,
        "start": {"x": [0.1, 0.2], "P": [[1e-9, 0.0], [0.0, 1e-9]]},
        "noise": {"W": [[0.2e-3, 0.0], [0.0, 0.2e-3]], "W_rate": [[1e-3, 0.0], [0.0, 1e-3]]},
        "domain": {"box": {"lower": [0.0, 0.0], "upper": [1.0, 0.5]}},
        "target": {"box": {"lower": [0.85, 0.15], "upper": [0.95, 0.25]}},
        "obstacles": [{"name": "obstacle", "box": {"lower": [0.4, 0.1], "upper": [0.6, 0.3]}}],
    })


#: The demo scenario's reference: over the obstacle.
_DEMO_VIA = np.array([[0.1, 0.2], [0.5, 0.4], [0.9, 0.2]])


def _reference(sc: Scenario, reference, steps: int, seed: int) -> np.ndarray:
    """Time-indexed reference means r_0..r_steps (metres)."""
    from ..smoother.warmstart import resample_means

    if reference is None:
        if sc.name == "mpc-demo":
            pts = _DEMO_VIA
        else:
            from ..planner import plan

            res = plan(sc, n_nodes=500, seed=seed, noise="per_step", max_radius=1.5)
            if not res.success:
                raise SolverError(f"mpc_demo: no reference path: planning failed ({res.message})")
            pts = res.path.x
    else:
        pts = reference.x if isinstance(reference, BeliefPath) else np.asarray(reference, float)
    pts = np.asarray(pts, float)
    if pts.shape[0] - 1 > steps:
        raise ValidationError("steps", f"the reference has {pts.shape[0] - 1} edges; give steps >= that")
    return resample_means(pts, steps)


class _MPCStage:
    """One Opti problem of horizon n (built once, reused with parameters)."""

    def __init__(self, sc: Scenario, funcs: dict, n: int, final: bool, alpha: float, track: float, sigma: float):
        d = sc.dim
        self.n, self.final, self.sigma = n, final, sigma
        tri = [(i, j) for i in range(d) for j in range(i + 1)]
        self.tri = tri
        opti = ca.Opti()
        self.opti = opti
        # scaled unknowns (numerics.md: metres break IPOPT): x = sigma x', S = L' L'^T / sigma^2, lam = lam' / sigma
        self.X = opti.variable(d, n)
        self.L = opti.variable(len(tri), n)
        self.lams = [opti.variable(h.n_faces, n) for h in sc.hazards]
        self.x_cur = opti.parameter(d)
        self.P_cur = opti.parameter(d, d)
        self.ref = opti.parameter(d, n)
        self.lam_ref = [opti.parameter(h.n_faces, n) for h in sc.hazards]
        W = ca.DM(sc.W)
        x_prev, P_prev = self.x_cur, self.P_cur
        cost = 0
        self.S_expr, self.P_expr = [], []
        for k in range(n):
            Lk = ca.MX.zeros(d, d)
            for p, (i, j) in enumerate(tri):
                Lk[i, j] = self.L[p, k]
            S = (Lk @ Lk.T) / sigma ** 2
            x_next = sigma * self.X[:, k]
            for h, lam in zip(sc.hazards, self.lams):
                m0, m1 = funcs[f"transition_{_slug(h.name)}"](x_prev, P_prev, x_next, W, lam[:, k] / sigma)
                opti.subject_to(m0 >= 1e-6 * sc.chi2)
                opti.subject_to(m1 >= 1e-6 * sc.chi2)
                opti.subject_to(lam[:, k] >= 0)
            P_hat = funcs["belief_predict"](P_prev, W)
            cost += ca.sumsqr(x_next - x_prev) + alpha * funcs["information_cost"](P_hat, S)
            cost += track * ca.sumsqr(x_next - self.ref[:, k])
            P_next = funcs["belief_update"](P_hat, S)
            self.S_expr.append(S)
            self.P_expr.append(P_next)
            x_prev, P_prev = x_next, P_next
        if final:     # in units of sigma, so IPOPT's 1e-8 feasibility tolerance is far below the margin
            opti.subject_to(funcs["target_containment"](x_prev, P_prev) / sigma >= 1e-6)
        # tiny proximal term on the certificates (flat directions, see nlp/ipopt.py)
        cost += 1e-4 * sum(ca.sumsqr(lam - lr) for lam, lr in zip(self.lams, self.lam_ref))
        opti.minimize(cost)
        from ..methods.ipopt import DEFAULT_IPOPT_OPTIONS

        opts = dict(DEFAULT_IPOPT_OPTIONS)
        opts.update(max_iter=1000, tol=1e-6)
        opti.solver("ipopt", {"print_time": False, "show_eval_warnings": False, "detect_simple_bounds": True}, opts)

    def solve(self, x_cur, P_cur, ref, guess_x, guess_L, guess_lam):
        o = self.opti
        o.set_value(self.x_cur, x_cur)
        o.set_value(self.P_cur, P_cur)
        o.set_value(self.ref, ref)
        o.set_initial(self.X, guess_x / self.sigma)
        o.set_initial(self.L, guess_L)
        for lam, lr, g in zip(self.lams, self.lam_ref, guess_lam):
            o.set_initial(lam, g)
            o.set_value(lr, g)
        try:
            sol = o.solve()
        except RuntimeError as exc:
            raise SolverError(f"mpc_demo: IPOPT failed at a receding-horizon step ({o.stats()['return_status']})") \
                from exc
        x = self.sigma * np.atleast_2d(sol.value(self.X).reshape(-1, self.n, order="F") if self.n > 1 else
                                       np.asarray(sol.value(self.X)).reshape(-1, 1))
        L = np.asarray(sol.value(self.L)).reshape(len(self.tri), self.n, order="F")
        lams = [np.asarray(sol.value(lam)).reshape(lam.shape[0], self.n, order="F") for lam in self.lams]
        S = [np.asarray(sol.value(Sk)).reshape(x.shape[0], x.shape[0]) for Sk in self.S_expr]
        return x, L, lams, S


def mpc_demo(scenario: Scenario | str | None = None, steps: int | None = None, horizon: int = 6,
             alpha: float | None = None, reference: BeliefPath | np.ndarray | None = None,
             track: float = 10.0, seed: int = 0) -> BeliefPath:
    """Receding-horizon belief-space MPC in ``casadi.Opti``, built only from
    the exported functions; returns the closed-loop belief path (SI).

    At every step t the MPC plans the next n = min(horizon, steps - t) means
    and sensing matrices from the current belief (x_t, P_t): cost
    sum ||x_k - x_{k-1}||^2 + alpha * information_cost + track * ||x_k - r_k||^2
    (r = a time-indexed reference), subject to the Theorem-1
    ``transition_<hazard>`` margins >= 1e-6 chi2 for every step and hazard
    (with certificate variables), beliefs propagated by ``belief_predict`` /
    ``belief_update``, and, once the horizon reaches the last step,
    ``target_containment`` >= 0 at the end. The first step is applied, the
    belief propagated with the same functions, and the loop repeats. Every
    applied transition is therefore certified by Theorem 1 and the path
    passes :func:`belief_nlp.verify`. If IPOPT fails at a step, the next step
    of the last successful plan is applied instead (it was certified from the
    same belief); ``path.meta["fallback_steps"]`` counts these.

    Parameters
    ----------
    scenario : None for :func:`demo_scenario` (a robot passing one obstacle),
        or any scenario / built-in name (e.g. "paper-multi").
    steps : closed-loop steps (default: 12 for the demo scenario, else the
        scenario's horizon K or 20).
    horizon : MPC prediction horizon.
    alpha : information weight (default: the scenario's).
    reference : means to track (BeliefPath or (m, d) array), resampled to
        ``steps``; default: over the obstacle for the demo scenario, else an
        IG-RRT* plan (``seed``, per-step noise).
    track : weight of the reference tracking term (1/m^2 relative to the
        control cost).

    Raises :class:`~belief_nlp.errors.SolverError` if IPOPT fails with no
    step of the last plan left.
    """
    from ..geometry import PolytopeSet, transition_clearances

    sc = demo_scenario() if scenario is None else (load_scenario(scenario) if isinstance(scenario, str) else scenario)
    if steps is None:
        steps = 12 if sc.name == "mpc-demo" else int(sc.K or 20)
    if not isinstance(steps, int) or steps < 1:
        raise ValidationError("steps", f"must be a positive integer, got {steps!r}")
    if not isinstance(horizon, int) or horizon < 1:
        raise ValidationError("horizon", f"must be a positive integer, got {horizon!r}")
    alpha = float(sc.alpha if alpha is None else alpha)
    d = sc.dim
    sigma = float(np.sqrt(np.max(np.linalg.eigvalsh(sc.W))))
    funcs = export_functions(sc)
    ref = _reference(sc, reference, steps, seed)
    hazards = PolytopeSet.build(sc.hazards)
    stages: dict[tuple[int, bool], _MPCStage] = {}

    # initial guess: the smoother's warm start of the reference (sensing added
    # where the open-loop beliefs would collide, smallest valid certificates)
    guess_x, guess_L, guess_lam = _initial_guess(sc, ref, sigma)

    xs = [sc.x0.copy()]
    Ss = []
    x_cur, P_cur = sc.x0.copy(), sc.P0.copy()
    tail: list[tuple[np.ndarray, np.ndarray]] = []     # unused steps of the last plan (all certified)
    fallbacks = 0
    for t in range(steps):
        n = min(horizon, steps - t)
        final = t + n == steps
        key = (n, final)
        if key not in stages:
            stages[key] = _MPCStage(sc, funcs, n, final, alpha, track, sigma)
        try:
            x_plan, L_plan, lam_plan, S_plan = stages[key].solve(
                x_cur, P_cur, ref[t + 1:t + 1 + n].T, guess_x[:, t:t + n], guess_L[:, t:t + n],
                [g[:, t:t + n] for g in guess_lam])
            tail = [(x_plan[:, k], S_plan[k]) for k in range(1, n)]
            x_next, S0 = x_plan[:, 0], S_plan[0]
        except SolverError:
            # the usual MPC fallback: the next step of the last plan, which that
            # solve certified from exactly this belief; none left -> give up
            if not tail:
                raise
            x_next, S0 = tail.pop(0)
            fallbacks += 1
            x_plan = L_plan = lam_plan = None
        # apply the first step and propagate the belief with the same functions
        S0 = 0.5 * (S0 + S0.T)
        P_hat = np.asarray(funcs["belief_predict"](P_cur, sc.W))
        P_next = np.asarray(funcs["belief_update"](P_hat, S0))
        clear = transition_clearances(x_cur, P_cur, x_next, sc.W, hazards, sc.chi2)
        if np.min(clear) < 0:          # cannot happen when IPOPT's constraints hold; never hide it
            raise SolverError(f"mpc_demo: step {t + 1} is not clear (margin {np.min(clear):.3g})")
        xs.append(x_next)
        Ss.append(S0)
        x_cur, P_cur = x_next, 0.5 * (P_next + P_next.T)
        # shift the plan into the guess for the next solve
        if x_plan is not None:
            guess_x[:, t:t + n] = x_plan
            guess_L[:, t:t + n] = L_plan
            for g, lp in zip(guess_lam, lam_plan):
                g[:, t:t + n] = lp
    S = np.concatenate([np.zeros((1, d, d)), np.array(Ss)])
    w, V = np.linalg.eigh(S)                                     # PSD by construction; clip rounding
    S = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
    return BeliefPath.from_sensing(np.array(xs), sc.P0, S, W=sc.W, noise="per_step",
                                   meta={"method": "mpc_demo", "scenario": sc.name, "horizon": horizon,
                                         "alpha": alpha, "steps": steps, "fallback_steps": fallbacks})


def _initial_guess(sc: Scenario, ref: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, list]:
    """Means, scaled sensing factors and scaled certificates (lam' = sigma lam)
    of :func:`belief_nlp.warm_start` applied to the reference: a feasible
    start for the first MPC solve (later solves start from the shifted plan).
    Smallest valid certificates start IPOPT better than the margin-maximising
    ones (see nlp/ipopt.py)."""
    from ..model.nlp_matrices import _psd_factor
    from ..smoother.warmstart import warm_start

    d = sc.dim
    K = ref.shape[0] - 1
    ws = warm_start(sc, BeliefPath.from_sensing(ref, sc.P0, np.zeros((K, d, d)), W=sc.W))
    tri = [(i, j) for i in range(d) for j in range(i + 1)]
    L = np.stack([[(_psd_factor(ws.path.S[k] * sigma ** 2))[i, j] for i, j in tri] for k in range(1, K + 1)], 1)
    lam = ws.lam * sigma
    return ws.path.x[1:].T.copy(), L, [lam[:, j, :h.n_faces].T.copy() for j, h in enumerate(sc.hazards)]
