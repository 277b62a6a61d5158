"""Adapter for ``casadi.Opti``: the whole belief layout of :mod:`.kit` over a horizon.

Usage (paper-multi closed loop; :func:`.closed_loop.closed_loop` does exactly this)::

    kit = BeliefMPC.build("paper-multi")
    mpc = OptiMPC(kit, horizon=10)                   # variables, dynamics, bundles, cost, IPOPT (built once)
    v = mpc.solve(kit.state(x, P), t, steps, ref, guess)   # (nu, horizon) plan
    x, P, S = kit.apply(x, P, v[:, 0])               # apply the first step
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SolverError, ValidationError
from .kit import BeliefMPC

__all__ = ["OptiMPC", "ipopt_options"]


def ipopt_options(warm: bool = False, **overrides) -> dict:
    """IPOPT settings of the MPC adapters: the smoother's defaults
    (docs/numerics.md), quiet. ``warm=True``: the settings of a solve that
    starts from a primal-feasible point (the shifted previous solution with
    its multipliers, or the first guess of a safe reference) -- keep the
    initial point (warm_start_init_point), a small barrier parameter and small
    pushes away from the bounds, so IPOPT does not first walk back to the
    central path."""
    from ..methods.ipopt import DEFAULT_IPOPT_OPTIONS

    opts = dict(DEFAULT_IPOPT_OPTIONS)
    opts.update(max_iter=500, tol=1e-6)
    if warm:
        opts.update(WARM_IPOPT_OPTIONS)
    opts.update(overrides)
    return opts


#: IPOPT options of a warm-started MPC solve (see :func:`ipopt_options`). mu_init
#: = 1e-7 <= tol / 10: IPOPT solves ONE barrier problem (with 1e-6 it solved
#: one at 1e-6, then lowered mu and solved again: ~7 iterations instead of ~3;
#: docs/mpc.md, "Speed")
WARM_IPOPT_OPTIONS: dict = {
    "warm_start_init_point": "yes", "mu_strategy": "monotone", "mu_init": 1e-7,
    "warm_start_bound_push": 1e-8, "warm_start_bound_frac": 1e-8, "warm_start_slack_bound_push": 1e-8,
    "warm_start_slack_bound_frac": 1e-8, "warm_start_mult_bound_push": 1e-8,
    "bound_push": 1e-8, "bound_frac": 1e-8,
}


class OptiMPC:
    """The belief MPC of ``horizon`` stages installed in a ``casadi.Opti``.

    Decision variables ``V`` (nu, N) inputs and, with ``shooting="multiple"``
    (the default), the states ``X[:, 1:N]`` (``X`` (nx, N+1): ``X[:, 0]`` is
    the parameter ``s0``, the current state; ``X[:, N]`` enters no row or
    cost and stays the expression ``step(X[:, N-1], V[:, N-1])``), tied to
    the dynamics by ``X[:, k+1] == step(X[:, k], V[:, k])`` -- a banded KKT
    system. ``shooting="single"``: ``X`` is the
    rollout of ``V`` (every iterate's covariance is a Kalman posterior, but
    every stage couples with all earlier ones: the KKT factorisation fills
    in and an IPOPT iteration costs ~2-3x more; docs/mpc.md, "Speed").
    Parameters ``s0``, ``gate`` (2, N), ``ref`` (d + J F, N) (scaled
    reference of the next means and certificates,
    :meth:`BeliefMPC.references`), ``p`` (n_p, N) (obstacle data and each
    hazard's confidence level, one column per stage: a risk allocation's
    levels, :meth:`SafetyBundle.stage_params`) and ``p_t`` (target data);
    change them with ``opti.set_value`` (or ``solve(..., p=...)``) at run time.
    Every stage gets ``kit.rows >= kit.lbg`` -- the certificate rows
    included. Pass your own ``opti`` to add constraints or cost terms
    (``extra_cost``) before :meth:`solve`.

    The IPOPT solver is built once, in the constructor (``expand=True``);
    :meth:`solve` only sets parameter and initial values. ``warm`` (default):
    IPOPT's warm-start settings (:data:`WARM_IPOPT_OPTIONS`) from the first
    solve on -- the first guess (:meth:`BeliefMPC.guess` of a safe reference)
    is primal feasible, and every later solve starts from the shifted
    previous plan. ``warm_duals`` (default): a solve at time t right after
    one at t - 1 also starts from that solve's multipliers shifted by one
    stage (the last stage's repeated). With a feasible appended stage
    (:meth:`BeliefMPC.hold`) and a proximal weight ``kit.prox`` > 0 IPOPT
    needs ~3 iterations a step (docs/mpc.md, "Speed").
    """

    def __init__(self, kit: BeliefMPC, horizon: int, opti: ca.Opti | None = None, extra_cost=0,
                 ipopt: dict | None = None, warm_duals: bool = True, warm: bool = True,
                 shooting: str = "multiple") -> None:
        if shooting not in ("multiple", "single"):
            raise ValidationError("shooting", f"must be 'multiple' or 'single', got {shooting!r}")
        self.kit, self.N, self.shooting = kit, int(horizon), shooting
        o = self.opti = ca.Opti() if opti is None else opti
        N = self.N
        self.V = o.variable(kit.nu, N)
        self.s0, self.gate, self.ref = o.parameter(kit.nx), o.parameter(2, N), o.parameter(kit.n_ref, N)
        self.p = o.parameter(kit.stage.function.size1_in("p"), N)       # one column per stage
        self.p_t = o.parameter(kit.terminal.function.size1_in("p"))
        rows, cost = kit.rows.map(N), kit.cost.map(N)
        if shooting == "multiple" and N > 1:
            # X[:, 1:N] are variables; X[:, N] enters no row or cost, so it stays the expression
            self._Xv = o.variable(kit.nx, N - 1)
            Xs = ca.horzcat(self.s0, self._Xv)
            self.X = ca.horzcat(Xs, kit.step(Xs[:, N - 1], self.V[:, N - 1]))
        else:
            self._Xv = None
            self.X = ca.horzcat(self.s0, kit.step.mapaccum(N)(self.s0, self.V))
        g = rows(self.X[:, :N], self.V, self.gate, self.p, ca.repmat(self.p_t, 1, N))
        o.subject_to(ca.vec(g) >= np.tile(kit.lbg, N))
        if self._Xv is not None:           # the dynamics, after all rows (multipliers shift block by block)
            o.subject_to(ca.vec(kit.step.map(N - 1)(self.X[:, :N - 1], self.V[:, :N - 1]) - self._Xv) == 0)
        o.minimize(ca.sum2(cost(self.X[:, :N], self.V, self.gate, self.ref)) + extra_cost)
        o.set_value(self.p, np.tile(kit.stage.params()[:, None], (1, N)))
        o.set_value(self.p_t, kit.terminal.params())
        self._ipopt = dict(ipopt or {})
        self.warm, self.warm_duals = bool(warm), bool(warm_duals)
        # show_eval_warnings off, as in the smoother's NLP: IPOPT backtracks from a
        # trial point where the cost is NaN (outside its domain), and CasADi would
        # print a timestamped warning for each one (hundreds per closed loop)
        o.solver("ipopt", {"expand": True, "print_time": False, "detect_simple_bounds": True,
                           "show_eval_warnings": False},
                 ipopt_options(warm=self.warm, **self._ipopt))
        self.last_stats: dict = {}
        self._last: tuple[int, np.ndarray] | None = None    # (t, multipliers) of the last solve

    def _warm_duals(self, t: int) -> None:
        """Start from the previous solve's multipliers shifted by one stage
        (the last stage's repeated)."""
        if not self.warm_duals or self._last is None or self._last[0] != t - 1:
            return
        lam, nr = self._last[1], self.kit.lbg.size * self.N
        nd = self.kit.nx * (self.N - 1) if self._Xv is not None else 0
        if lam.size != nr + nd:                        # constraints of the caller's own: no shift
            return
        blocks = [lam[:nr].reshape(-1, self.N, order="F")]
        if nd:
            blocks.append(lam[nr:].reshape(-1, self.N - 1, order="F"))
        self.opti.set_initial(self.opti.lam_g, np.concatenate(
            [np.hstack([L[:, 1:], L[:, -1:]]).ravel(order="F") for L in blocks]))

    def solve(self, state: np.ndarray, t: int, steps: int, ref: np.ndarray, guess: np.ndarray,
              p: np.ndarray | None = None) -> np.ndarray:
        """Solve from ``state`` at time t of a run of ``steps``; ``ref`` (d + J F, N)
        from :meth:`BeliefMPC.references`, ``guess`` (nu, N) inputs (their
        rollout from ``state`` is the states' initial value), ``p`` (n_p, N)
        the stages' obstacle data and levels (None: as before). Returns
        the planned inputs (nu, N); raises SolverError if IPOPT fails."""
        o, kit = self.opti, self.kit
        if p is not None:
            o.set_value(self.p, p)
        o.set_value(self.s0, state)
        o.set_value(self.gate, kit.gates(t, self.N, steps))
        o.set_value(self.ref, ref)
        o.set_initial(self.V, guess)
        if self._Xv is not None:
            o.set_initial(self._Xv, kit.rollout(state, guess)[:, 1:self.N])
        self._warm_duals(t)
        try:
            value = o.solve().value
            self.converged = True
        except RuntimeError as exc:
            # IPOPT stopped early: hand back its last iterate; the caller checks
            # the step it applies exactly (a closed loop never trusts it blindly)
            self.converged = False
            value = o.debug.value
            if not np.all(np.isfinite(np.asarray(value(self.V)))):
                self.last_stats = o.stats()
                raise SolverError(f"Opti/IPOPT failed ({self.last_stats.get('return_status')})") from exc
        self.last_stats = o.stats()
        self._last = (t, np.asarray(value(o.lam_g), float).ravel())
        return np.asarray(value(self.V), float).reshape(kit.nu, self.N, order="F")
