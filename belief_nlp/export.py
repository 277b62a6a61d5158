"""CasADi functions of the belief model for MPC stacks, and an MPC demo.

Every function here is a named ``casadi.Function`` built from ``SX``
symbols, so it can be called on ``SX`` (it is inlined: code generation and
``expand`` see plain expressions), on ``MX`` (``casadi.Opti``) or on
numbers, and saved with ``Function.save(file)`` / loaded with
``casadi.Function.load(file)`` (see :func:`save_functions`).

Units: SI throughout. Positions x and face offsets b in metres; covariances
P, P_hat, W in m^2; sensing information S in 1/m^2; face normals A
dimensionless (unit rows, as :class:`~belief_nlp.polytope.Polytope` stores
them); certificates lam in 1/m; information in nats. Margins are
dimensionless ("squared Mahalanobis distance minus chi2" for clearances)
except target containment, in metres. Every margin reads ``>= 0`` = safe.

Functions (inputs -> outputs)
-----------------------------
``belief_predict``     (P, W) -> (P_hat)                    P_hat = P + W (paper eq. 2)
``belief_update``      (P_hat, S) -> (P)                    P = (P_hat^-1 + S)^-1, computed as
                       (I + P_hat S)^-1 P_hat so a singular prior is never inverted
``information_cost``   (P_hat, S) -> (nats)                 1/2 log det(P_hat) - 1/2 log det(P)
                       = 1/2 log det(I + P_hat S) (matrix determinant lemma)
``ellipse_clearance``  (x, P, lam[, A, b]) -> (margin)      Lemma 1: -lam^T A P A^T lam
                       + 2 lam^T (A x - b) - chi2; >= 0 for some lam >= 0 iff the
                       ellipse E(x, P) misses {A y <= b}
``transition_clearance`` (x_prev, P_prev, x_next, W, lam[, A, b]) -> (margin_start, margin_end)
                       Theorem 1 with C5: the two ends with one common lam,
                       P_prev at the start and P_prev + W at the end; both >= 0 for
                       some lam >= 0 iff the whole transition is clear
``target_containment`` (x, P) -> (margins)                  per target face
                       b_n - a_n^T x - chi sqrt(a_n^T P a_n) (metres), final_cond
                       with C4

:func:`export_functions` returns them all for a scenario (A, b and chi2 fixed,
one clearance function per hazard). :func:`dompc_constraints` and
:func:`acados_constraints` give the raw constraint expressions in those
tools' conventions; :func:`mpc_demo` runs a receding-horizon MPC in
``casadi.Opti`` built only from these functions.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import casadi as ca
import numpy as np

from .errors import SolverError, ValidationError
from .model import terms
from .path import BeliefPath
from .scenario import Scenario, load_scenario, scenario_from_dict

__all__ = [
    "belief_predict", "belief_update", "information_cost", "ellipse_clearance", "transition_clearance",
    "target_containment", "export_functions", "save_functions", "load_functions", "clearance_margins",
    "dompc_constraints", "acados_constraints", "ACADOS_INFTY", "demo_scenario", "mpc_demo",
]

#: Upper bound used for one-sided acados constraints (acados treats bounds of
#: this size as infinite for the HPIPM QP solver; its constant ACADOS_INFTY).
ACADOS_INFTY = 1e10


def _check_dim(d: Any) -> int:
    if not isinstance(d, (int, np.integer)) or isinstance(d, bool) or d < 1:
        raise ValidationError("d", f"must be a positive integer, got {d!r}")
    return int(d)


# ------------------------------------------------------------ belief maths
def belief_predict(d: int = 2, name: str = "belief_predict") -> ca.Function:
    """(P [m^2], W [m^2]) -> (P_hat [m^2]): the prior after one step, P + W."""
    d = _check_dim(d)
    P = ca.SX.sym("P", d, d)
    W = ca.SX.sym("W", d, d)
    return ca.Function(name, [P, W], [terms.predict(P, W)], ["P", "W"], ["P_hat"])


def belief_update(d: int = 2, name: str = "belief_update") -> ca.Function:
    """(P_hat [m^2], S [1/m^2]) -> (P [m^2]): the posterior (P_hat^-1 + S)^-1."""
    d = _check_dim(d)
    Ph = ca.SX.sym("P_hat", d, d)
    S = ca.SX.sym("S", d, d)
    return ca.Function(name, [Ph, S], [terms.update_cov(Ph, S)], ["P_hat", "S"], ["P"])


def information_cost(d: int = 2, name: str = "information_cost") -> ca.Function:
    """(P_hat [m^2], S [1/m^2]) -> (nats): 1/2 log det(I + P_hat S), which equals
    1/2 log det P_hat - 1/2 log det P for P = belief_update(P_hat, S)."""
    d = _check_dim(d)
    Ph = ca.SX.sym("P_hat", d, d)
    S = ca.SX.sym("S", d, d)
    return ca.Function(name, [Ph, S], [terms.information_cov(Ph, S)], ["P_hat", "S"], ["nats"])


def _fixed_or_inputs(d: int, A: Any, b: Any, n_faces: int | None) -> tuple[ca.SX | ca.DM, ca.SX | ca.DM, list, list]:
    if (A is None) != (b is None):
        raise ValidationError("A", "give both A and b (fixed at export time) or neither (inputs)")
    if A is not None:
        A = np.atleast_2d(np.asarray(A, float))
        b = np.atleast_1d(np.asarray(b, float))
        if A.shape[1] != d or b.shape != (A.shape[0],):
            raise ValidationError("A", f"A must be (f, {d}) and b (f,), got {A.shape} and {b.shape}")
        return ca.DM(A), ca.DM(b), [], []
    if n_faces is None or not isinstance(n_faces, (int, np.integer)) or n_faces < 1:
        raise ValidationError("n_faces", f"give the number of faces when A and b are inputs, got {n_faces!r}")
    As = ca.SX.sym("A", int(n_faces), d)
    bs = ca.SX.sym("b", int(n_faces))
    return As, bs, [As, bs], ["A", "b"]


def _clearance_setup(d: Any, chi2: Any, A: Any, b: Any, n_faces: int | None):
    """Checked (d, chi2) and the polytope as constants or as extra inputs."""
    d = _check_dim(d)
    if chi2 is None or not chi2 > 0:
        raise ValidationError("chi2", f"must be a number > 0, got {chi2!r}")
    return (d, float(chi2)) + _fixed_or_inputs(d, A, b, n_faces)


def ellipse_clearance(d: int = 2, chi2: float | None = None, A: Any = None, b: Any = None,
                      n_faces: int | None = None, name: str = "ellipse_clearance") -> ca.Function:
    """Lemma-1 clearance of the ellipse E(x, P) from the polytope {A y <= b}.

    Inputs x [m] (d), P [m^2] (d, d), lam [1/m] (f) and, unless A and b are
    fixed here, A (f, d) and b [m] (f). Output ``margin`` = -lam^T A P A^T lam
    + 2 lam^T (A x - b) - chi2: for every lam >= 0 a lower bound on the
    squared Mahalanobis distance minus chi2, equal to it at the best lam.
    ``chi2`` is the squared confidence radius (required).
    """
    d, chi2, A_, b_, extra, extra_names = _clearance_setup(d, chi2, A, b, n_faces)
    x = ca.SX.sym("x", d)
    P = ca.SX.sym("P", d, d)
    lam = ca.SX.sym("lam", int(A_.shape[0]))
    m = terms.collision_margin_cov(x, P, lam, A_, b_, chi2)
    return ca.Function(name, [x, P, lam] + extra, [m], ["x", "P", "lam"] + extra_names, ["margin"])


def transition_clearance(d: int = 2, chi2: float | None = None, A: Any = None, b: Any = None,
                         n_faces: int | None = None, name: str = "transition_clearance") -> ca.Function:
    """Theorem-1 clearance of the transition (x_prev, P_prev) -> x_next under noise W.

    Inputs x_prev [m], P_prev [m^2] (the posterior at the start), x_next [m],
    W [m^2] (the step's process noise), lam [1/m] (f) -- one lam for both
    ends -- and A, b unless fixed here. Outputs ``margin_start`` (Lemma 1 at
    x_prev, P_prev) and ``margin_end`` (at x_next, P_prev + W); the whole
    transition x(s), P(s) = P_prev + s W, s in [0, 1], is clear iff both are
    >= 0 for some lam >= 0 (Theorem 1 with C5).
    """
    d, chi2, A_, b_, extra, extra_names = _clearance_setup(d, chi2, A, b, n_faces)
    x0 = ca.SX.sym("x_prev", d)
    P0 = ca.SX.sym("P_prev", d, d)
    x1 = ca.SX.sym("x_next", d)
    W = ca.SX.sym("W", d, d)
    lam = ca.SX.sym("lam", int(A_.shape[0]))
    m0 = terms.collision_margin_cov(x0, P0, lam, A_, b_, chi2)
    m1 = terms.collision_margin_cov(x1, terms.predict(P0, W), lam, A_, b_, chi2)
    return ca.Function(name, [x0, P0, x1, W, lam] + extra, [m0, m1],
                       ["x_prev", "P_prev", "x_next", "W", "lam"] + extra_names, ["margin_start", "margin_end"])


def target_containment(A: Any, b: Any, chi2: float, name: str = "target_containment") -> ca.Function:
    """(x [m], P [m^2]) -> (margins [m], one per face of the target {A y <= b}):
    b_n - a_n^T x - chi sqrt(a_n^T P a_n); all >= 0 iff E(x, P) lies in the target."""
    A = np.atleast_2d(np.asarray(A, float))
    b = np.atleast_1d(np.asarray(b, float))
    if b.shape != (A.shape[0],):
        raise ValidationError("b", f"must have one entry per row of A ({A.shape[0]}), got {b.shape}")
    if not chi2 > 0:
        raise ValidationError("chi2", f"must be a number > 0, got {chi2!r}")
    d = A.shape[1]
    x = ca.SX.sym("x", d)
    P = ca.SX.sym("P", d, d)
    m = ca.vertcat(*[terms.target_margin_cov(x, P, ca.DM(a), float(bn), float(chi2)) for a, bn in zip(A, b)])
    return ca.Function(name, [x, P], [m], ["x", "P"], ["margins"])


def _slug(text: str) -> str:
    return re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower() or "hazard"


def export_functions(scenario: Scenario | str) -> dict[str, ca.Function]:
    """Every exported function for one scenario, chi2 and polytopes fixed.

    Keys: "belief_predict", "belief_update", "information_cost",
    "target_containment", and per hazard j (obstacles, then domain walls, the
    order of ``scenario.hazards``) "clearance_<name>" (the Lemma-1 form) and
    "transition_<name>" (the Theorem-1 form), e.g. "transition_obstacle_1",
    "transition_wall_0". Function names equal the keys.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    d = sc.dim
    out = {
        "belief_predict": belief_predict(d),
        "belief_update": belief_update(d),
        "information_cost": information_cost(d),
        "target_containment": target_containment(sc.target.A, sc.target.b, sc.chi2),
    }
    for h in sc.hazards:
        s = _slug(h.name)
        out[f"clearance_{s}"] = ellipse_clearance(d, sc.chi2, h.A, h.b, name=f"clearance_{s}")
        out[f"transition_{s}"] = transition_clearance(d, sc.chi2, h.A, h.b, name=f"transition_{s}")
    return out


def save_functions(functions: dict[str, ca.Function], directory: str | Path) -> list[Path]:
    """Save each function to ``directory/<key>.casadi`` (CasADi serialisation);
    :func:`load_functions` reads them back."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for key, fn in functions.items():
        p = directory / f"{key}.casadi"
        fn.save(str(p))
        written.append(p)
    return written


def load_functions(directory: str | Path) -> dict[str, ca.Function]:
    """The functions saved by :func:`save_functions`, keyed by file stem."""
    return {p.stem: ca.Function.load(str(p)) for p in sorted(Path(directory).glob("*.casadi"))}


# ------------------------------------------------------ constraint helpers
def clearance_margins(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None,
                      x_final=None, P_final=None) -> tuple[list[str], Any]:
    """All safety margins of one transition as one column expression (>= 0 safe).

    ``x_prev`` (d), ``P_prev`` (d, d), ``x_next`` (d) and ``lams`` (one (f_j,)
    vector per hazard of ``scenario.hazards``) may be SX, MX or numbers; ``W``
    defaults to the scenario's per-step noise. Rows: for each hazard the
    Theorem-1 start and end margins; with ``x_final``/``P_final``, the target
    containment margins (metres) at the end. Returns (row names, expression).
    """
    funcs = export_functions(scenario)
    if len(lams) != len(scenario.hazards):
        raise ValidationError("lams", f"give one certificate per hazard ({len(scenario.hazards)}), got {len(lams)}")
    W = scenario.W if W is None else W
    names, rows = [], []
    for h, lam in zip(scenario.hazards, lams):
        s = _slug(h.name)
        m0, m1 = funcs[f"transition_{s}"](x_prev, P_prev, x_next, W, lam)
        names += [f"{s}_start", f"{s}_end"] + [f"{s}_lam_{f}" for f in range(h.n_faces)]
        rows += [m0, m1, ca.vec(lam)]
    if x_final is not None:
        tm = funcs["target_containment"](x_final, P_final)
        names += [f"target_face_{n}" for n in range(scenario.target.n_faces)]
        rows.append(tm)
    return names, ca.vertcat(*rows)


def dompc_constraints(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None, x_final=None,
                      P_final=None, margin: float = 0.0) -> list[tuple[str, Any, float]]:
    """The safety constraints in do-mpc's convention.

    do-mpc's ``mpc.set_nl_cons(name, expr, ub)`` keeps ``expr <= ub``; a
    margin m >= margin becomes ``expr = -m``, ``ub = -margin``. Returns one
    (name, expr, ub) triple per row of :func:`clearance_margins`, e.g.::

        for name, expr, ub in dompc_constraints(sc, x, P, x_next, lams):
            mpc.set_nl_cons(name, expr, ub=ub)
    """
    names, h = clearance_margins(scenario, x_prev, P_prev, x_next, lams, W, x_final, P_final)
    return [(n, -h[i], -_row_margin(n, margin)) for i, n in enumerate(names)]


def acados_constraints(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None, x_final=None,
                       P_final=None, margin: float = 0.0) -> tuple[Any, np.ndarray, np.ndarray]:
    """The safety constraints in acados' convention ``lh <= h(x, u) <= uh``.

    Returns (h, lh, uh) with h = the margins of :func:`clearance_margins`,
    lh = margin, uh = :data:`ACADOS_INFTY` (one-sided); use as
    ``model.con_h_expr = h; ocp.constraints.lh = lh; ocp.constraints.uh = uh``
    (or the ``_e`` variants at the terminal stage).
    """
    names, h = clearance_margins(scenario, x_prev, P_prev, x_next, lams, W, x_final, P_final)
    return h, np.array([_row_margin(n, margin) for n in names]), np.full(len(names), ACADOS_INFTY)


def _row_margin(name: str, margin: float) -> float:
    """Lower bound of a row: ``margin`` for safety margins, 0 for certificate rows."""
    return 0.0 if "_lam_" in name else float(margin)


# ------------------------------------------------------------------- MPC demo
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
    from .smoother.warmstart import resample_means

    if reference is None:
        if sc.name == "mpc-demo":
            pts = _DEMO_VIA
        else:
            from .planner import plan

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
        from .methods.ipopt import DEFAULT_IPOPT_OPTIONS

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
    from .geometry import PolytopeSet, transition_clearances

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
    from .model.nlp_form import _psd_factor
    from .smoother.warmstart import warm_start

    d = sc.dim
    K = ref.shape[0] - 1
    ws = warm_start(sc, BeliefPath.from_sensing(ref, sc.P0, np.zeros((K, d, d)), W=sc.W))
    tri = [(i, j) for i in range(d) for j in range(i + 1)]
    L = np.stack([[(_psd_factor(ws.path.S[k] * sigma ** 2))[i, j] for i, j in tri] for k in range(1, K + 1)], 1)
    lam = ws.lam * sigma
    return ws.path.x[1:].T.copy(), L, [lam[:, j, :h.n_faces].T.copy() for j, h in enumerate(sc.hazards)]
