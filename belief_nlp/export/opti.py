"""Adapter for ``casadi.Opti``: the whole belief layout of :mod:`.kit` over a horizon.

Usage (paper-multi closed loop; :func:`.closed_loop.closed_loop` does exactly this)::

    kit = BeliefMPC.build("paper-multi")
    mpc = OptiMPC(kit, horizon=10)                   # variables, dynamics, bundles, cost, IPOPT
    v = mpc.solve(kit.state(x, P), t, steps, ref, guess)   # (nu, horizon) plan
    x, P, S = kit.apply(x, P, v[:, 0])               # apply the first step
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SolverError
from .kit import BeliefMPC

__all__ = ["OptiMPC", "ipopt_options"]


def ipopt_options(**overrides) -> dict:
    """IPOPT settings of the MPC adapters: the smoother's defaults (docs/numerics.md), quiet."""
    from ..methods.ipopt import DEFAULT_IPOPT_OPTIONS

    opts = dict(DEFAULT_IPOPT_OPTIONS)
    opts.update(max_iter=500, tol=1e-6)
    opts.update(overrides)
    return opts


class OptiMPC:
    """The belief MPC of ``horizon`` stages installed in a ``casadi.Opti``.

    Decision variables ``V`` (nu, N) inputs; ``X`` (nx, N+1) the states
    rolled out from them (single shooting);
    parameters ``s0`` (current state), ``gate`` (2, N), ``ref`` (d + J F, N)
    (scaled reference of the next means and certificates, :meth:`BeliefMPC.references`), ``p``/``p_t`` (obstacle and target
    data: change them with ``opti.set_value`` to move obstacles at run time).
    Every stage gets ``kit.rows >= kit.lbg`` -- the certificate rows
    included. Pass your own ``opti`` to add constraints or cost terms
    (``extra_cost``) before :meth:`solve`.
    """

    def __init__(self, kit: BeliefMPC, horizon: int, opti: ca.Opti | None = None, extra_cost=0,
                 ipopt: dict | None = None) -> None:
        self.kit, self.N = kit, int(horizon)
        o = self.opti = ca.Opti() if opti is None else opti
        N = self.N
        # single shooting: the states are the rollout of the inputs, so every
        # iterate's covariance is a Kalman posterior (positive definite; the
        # information term's log det is always defined)
        self.V = o.variable(kit.nu, N)
        self.s0, self.gate, self.ref = o.parameter(kit.nx), o.parameter(2, N), o.parameter(kit.d + kit.stage.n_lam, N)
        self.p = o.parameter(kit.stage.function.size1_in("p"))
        self.p_t = o.parameter(kit.terminal.function.size1_in("p"))
        rows, cost = kit.rows.map(N), kit.cost.map(N)
        self.X = ca.horzcat(self.s0, kit.step.mapaccum(N)(self.s0, self.V))
        g = rows(self.X[:, :N], self.V, self.gate, ca.repmat(self.p, 1, N), ca.repmat(self.p_t, 1, N))
        o.subject_to(ca.vec(g) >= np.tile(kit.lbg, N))
        o.minimize(ca.sum2(cost(self.X[:, :N], self.V, self.gate, self.ref)) + extra_cost)
        o.set_value(self.p, kit.stage.params())
        o.set_value(self.p_t, kit.terminal.params())
        o.solver("ipopt", {"expand": True, "print_time": False, "detect_simple_bounds": True},
                 ipopt_options(**(ipopt or {})))
        self.last_stats: dict = {}

    def solve(self, state: np.ndarray, t: int, steps: int, ref: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """Solve from ``state`` at time t of a run of ``steps``; ``ref`` (d + J F, N)
        from :meth:`BeliefMPC.references`, ``guess`` (nu, N) inputs. Returns
        the planned inputs (nu, N); raises SolverError if IPOPT fails."""
        o, kit = self.opti, self.kit
        o.set_value(self.s0, state)
        o.set_value(self.gate, kit.gates(t, self.N, steps))
        o.set_value(self.ref, ref)
        o.set_initial(self.V, guess)
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
        return np.asarray(value(self.V), float).reshape(kit.nu, self.N, order="F")
