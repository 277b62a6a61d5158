"""Adapter for do-mpc: the belief layout of :mod:`.kit` as a discrete do-mpc model and MPC.

Usage (paper-multi closed loop; :func:`.closed_loop.closed_loop` does exactly this)::

    kit = BeliefMPC.build("paper-multi")
    mpc = DompcMPC(kit, horizon=10)                  # model, set_nl_cons, objective, IPOPT
    v = mpc.solve(kit.state(x, P), t, steps, ref, guess)   # (nu, horizon) plan
    x, P, S = kit.apply(x, P, v[:, 0])

What is installed (:func:`dompc_model`, :func:`dompc_controller`):

* a **discrete SX model**: state ``s`` (kit.nx), input ``v`` (kit.nu), the
  time-varying parameters ``gate`` (2), ``ref`` (d + J F), ``p`` and ``p_t``
  (obstacle and target data: moving an obstacle is a new tvp value, no new
  model), ``set_rhs("s", kit.step(s, v))``;
* ``set_nl_cons("belief_safety", -kit.rows(s, v, ...), ub=-kit.lbg)``: do-mpc
  evaluates nl_cons on (x_k, u_k), which is exactly the layout of
  ``kit.rows`` -- the Theorem-1 rows of the transition s_k -> step(s_k, v_k)
  and the certificate rows ``lam >= 0`` (they cannot be dropped) plus the
  **terminal part**: the target rows of the next belief, switched on by the
  ``gate`` tvp at the last stage of the run (do-mpc has no terminal
  nonlinear constraint, so the terminal bundle lives in the stage that
  produces the final belief);
* ``lterm = kit.cost(s, v, gate, ref)``, ``mterm = 0``; bounds
  ``diag P' >= 0`` on the state (do-mpc shoots multiply: its iterates'
  covariances are variables).
"""

from __future__ import annotations

import warnings

import casadi as ca
import numpy as np

from ..errors import SolverError
from .kit import BeliefMPC
from .opti import ipopt_options

__all__ = ["DompcMPC", "dompc_model", "dompc_controller"]


def _do_mpc():
    with warnings.catch_warnings():                 # optional do-mpc features announce themselves
        warnings.simplefilter("ignore")
        import do_mpc
    return do_mpc


def dompc_model(kit: BeliefMPC):
    """The discrete SX do-mpc model of ``kit`` (set up; see the module doc)."""
    do_mpc = _do_mpc()
    m = do_mpc.model.Model("discrete", "SX")
    s = m.set_variable("_x", "s", (kit.nx, 1))
    v = m.set_variable("_u", "v", (kit.nu, 1))
    gate = m.set_variable("_tvp", "gate", (2, 1))
    ref = m.set_variable("_tvp", "ref", (kit.n_ref, 1))
    p = m.set_variable("_tvp", "p", (kit.stage.function.size1_in("p"), 1))
    p_t = m.set_variable("_tvp", "p_t", (kit.terminal.function.size1_in("p"), 1))
    m.set_rhs("s", kit.step(s, v))
    m.set_expression("rows", kit.rows(s, v, gate, p, p_t))
    m.set_expression("cost", kit.cost(s, v, gate, ref))
    m.setup()
    return m


def dompc_controller(kit: BeliefMPC, model, horizon: int, tvp_fun, ipopt: dict | None = None, warm: bool = True):
    """The do-mpc MPC of ``model`` over ``horizon`` stages with the safety rows
    as ``set_nl_cons``; ``tvp_fun(template, t_now)`` fills do-mpc's tvp
    template and returns it (set up). ``warm``: IPOPT's warm-start settings
    (:data:`.opti.WARM_IPOPT_OPTIONS`) -- do-mpc starts every solve from its
    last solution and multipliers, so with ``kit.prox`` > 0 IPOPT needs
    ~5 iterations instead of ~45 (docs/mpc.md, "Speed")."""
    do_mpc = _do_mpc()
    mpc = do_mpc.controller.MPC(model)
    opts = {"ipopt." + k: v for k, v in ipopt_options(warm=warm, **(ipopt or {})).items()}
    mpc.settings.supress_ipopt_output()
    mpc.set_param(n_horizon=int(horizon), t_step=1.0, n_robust=0, store_full_solution=False,
                  nlpsol_opts={**opts, "print_time": False, "expand": True})
    mpc.set_objective(lterm=model.aux["cost"], mterm=ca.SX(0))
    mpc.set_rterm(v=0.0)            # no input-rate penalty: the stage cost already prices each move
    mpc.set_nl_cons("belief_safety", -model.aux["rows"], ub=-kit.lbg.reshape(-1, 1))
    lb = np.full(kit.nx, -np.inf)
    lb[[kit.d + n for n, (i, j) in enumerate(kit.tri) if i == j]] = 0.0
    mpc.bounds["lower", "_x", "s"] = lb
    template = mpc.get_tvp_template()
    mpc.set_tvp_fun(lambda t_now: tvp_fun(template, t_now))
    with warnings.catch_warnings():
        # do-mpc's setup applies numpy functions to CasADi values (CasADi 3.8 warns, issue #2959);
        # harmless here and not ours to change
        warnings.filterwarnings("ignore", message=r"\s*casadi: a numpy function was called on a casadi value",
                                category=FutureWarning)
        mpc.setup()
    return mpc


class DompcMPC:
    """The belief MPC of ``horizon`` stages in do-mpc (module doc).

    ``solve`` sets the tvp values (gates of the run, references, obstacle
    data ``self.p``/``self.p_t`` -- assign new values to move obstacles;
    ``self.p`` may hold one column per stage, e.g. a risk allocation's levels),
    writes the guess and its rollout into do-mpc's initial point
    (``opt_x_num``) and calls ``make_step``.
    """

    def __init__(self, kit: BeliefMPC, horizon: int, ipopt: dict | None = None, warm: bool = True) -> None:
        self.kit, self.N = kit, int(horizon)
        self.p, self.p_t = kit.stage.params(), kit.terminal.params()
        self._gate = np.zeros((2, self.N))
        self._ref = np.zeros((kit.n_ref, self.N))
        self.model = dompc_model(kit)
        self.mpc = dompc_controller(kit, self.model, self.N, self._tvp, ipopt, warm)
        self.mpc.x0 = np.zeros(kit.nx)
        self.mpc.set_initial_guess()
        self.last_stats: dict = {}
        # flat indices into do-mpc's structures, looked up once: a step writes
        # and reads whole numpy blocks instead of ~75 struct item accesses
        N, f = self.N, self.mpc.opt_x.f
        self._iu = np.array([f["_u", k, 0] for k in range(N)]).T            # (nu, N)
        self._ix = np.array([f["_x", k, 0, -1] for k in range(N + 1)]).T    # (nx, N+1)

    def _tvp(self, tpl, t_now: float):
        if getattr(self, "_itvp", None) is None:                       # (do-mpc's setup calls this too)
            self._itvp = {name: np.array([tpl.struct.f["_tvp", k, name] for k in range(self.N + 1)]).T
                          for name in ("gate", "ref", "p", "p_t")}
        c = np.minimum(np.arange(self.N + 1), self.N - 1)
        gate = np.hstack([self._gate, np.zeros((2, 1))])
        P = np.asarray(self.p, float)
        P = np.tile(P.reshape(-1, 1), self.N + 1) if P.ndim == 1 else P[:, c]     # per stage: (n_p, N)
        vals = {"gate": gate, "ref": self._ref[:, c], "p": P,
                "p_t": np.tile(np.reshape(self.p_t, (-1, 1)), self.N + 1)}
        v = np.asarray(tpl.master, float).ravel()
        for name, idx in self._itvp.items():
            v[idx] = vals[name]
        tpl.master = ca.DM(v)
        return tpl

    def solve(self, state: np.ndarray, t: int, steps: int, ref: np.ndarray, guess: np.ndarray,
              p: np.ndarray | None = None) -> np.ndarray:
        """Solve from ``state`` at time t of a run of ``steps`` (arguments as
        :meth:`.OptiMPC.solve`; ``p`` (n_p, N): each stage's obstacle data and
        levels, kept in ``self.p``); returns the planned inputs (nu, N)."""
        kit, m = self.kit, self.mpc
        if p is not None:
            self.p = np.asarray(p, float)
        self._gate, self._ref = kit.gates(t, self.N, steps), np.asarray(ref, float)
        w = np.asarray(m.opt_x_num.master, float).ravel()
        w[self._iu] = guess
        w[self._ix] = kit.rollout(state, guess)
        m.opt_x_num.master = ca.DM(w)
        m.make_step(np.asarray(state, float).reshape(-1, 1))
        self.last_stats = dict(m.solver_stats)
        self.converged = bool(self.last_stats.get("success", False))
        V = np.asarray(m.opt_x_num.master, float).ravel()[self._iu]
        if not np.all(np.isfinite(V)):
            raise SolverError(f"do-mpc/IPOPT failed ({self.last_stats.get('return_status')})")
        return V
