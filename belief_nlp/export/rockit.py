"""Adapter for rockit: the belief layout of :mod:`.kit` as a discrete rockit ``Ocp``.

Usage (paper-multi closed loop; :func:`.closed_loop.closed_loop` does exactly this)::

    kit = BeliefMPC.build("paper-multi")
    mpc = RockitMPC(kit, horizon=10)                 # Ocp, set_next, subject_to, objective, IPOPT
    v = mpc.solve(kit.state(x, P), t, steps, ref, guess)   # (nu, horizon) plan
    x, P, S = kit.apply(x, P, v[:, 0])

What is installed (:func:`rockit_ocp`), with ``T = horizon`` and
``MultipleShooting(N=horizon)`` (one control interval per MPC stage):

* ``s = ocp.state(kit.nx)``, ``v = ocp.control(kit.nu)``,
  ``ocp.set_next(s, kit.step(s, v))`` (a discrete system), and
  ``ocp.at_t0(s) == s0`` with the parameter ``s0``;
* control-grid parameters ``gate`` (2) and ``ref`` (d + J F), plain
  parameters ``p`` and ``p_t`` (obstacle and target data: ``set_value`` moves
  obstacles without a new Ocp);
* ``ocp.subject_to(kit.rows(s, v, gate, p, p_t) >= kit.lbg, include_last=False)``:
  the Theorem-1 rows of every stage with their certificate rows (which
  cannot be dropped) and the target rows of the next belief, switched on by
  ``gate`` at the stage that produces the run's final belief -- also when the
  run ends inside the horizon; when the run's end is the horizon's end this
  is the terminal constraint on ``ocp.at_tf(s)``;
* the objective ``ocp.sum(kit.cost(s, v, gate, ref))``; ``diag P' >= 0``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SolverError
from .kit import BeliefMPC
from .opti import ipopt_options

__all__ = ["RockitMPC", "rockit_ocp"]


def rockit_ocp(kit: BeliefMPC, horizon: int, ipopt: dict | None = None, warm: bool = True) -> tuple:
    """The rockit Ocp of ``kit`` over ``horizon`` stages (module doc).

    Returns ``(ocp, symbols)`` with symbols a dict of ``s``, ``v``, ``s0``,
    ``gate``, ``ref``, ``p``, ``p_t`` and ``rows`` (the installed stage
    expression, ``rows >= kit.lbg``). ``warm``: IPOPT's warm-start settings
    (:data:`.opti.WARM_IPOPT_OPTIONS`)."""
    from rockit import MultipleShooting, Ocp

    N = int(horizon)
    ocp = Ocp(T=float(N))
    s, v = ocp.state(kit.nx), ocp.control(kit.nu)
    ocp.set_next(s, kit.step(s, v))
    sym = {"s": s, "v": v, "s0": ocp.parameter(kit.nx),
           "gate": ocp.parameter(2, grid="control"), "ref": ocp.parameter(kit.n_ref, grid="control"),
           "p": ocp.parameter(kit.stage.function.size1_in("p"), grid="control"),     # per stage (levels)
           "p_t": ocp.parameter(kit.terminal.function.size1_in("p"))}
    ocp.subject_to(ocp.at_t0(s) == sym["s0"])
    sym["rows"] = rows = kit.rows(s, v, sym["gate"], sym["p"], sym["p_t"])
    ocp.subject_to(rows >= kit.lbg, include_last=False)
    for n, (i, j) in enumerate(kit.tri):
        if i == j:
            ocp.subject_to(s[kit.d + n] >= 0, include_first=False)
    ocp.add_objective(ocp.sum(kit.cost(s, v, sym["gate"], sym["ref"])))
    ocp.set_value(sym["p"], np.tile(kit.stage.params()[:, None], (1, N)))
    ocp.set_value(sym["p_t"], kit.terminal.params())
    ocp.method(MultipleShooting(N=N))
    ocp.solver("ipopt", {"expand": True, "print_time": False,
                         **{"ipopt." + k: val for k, val in ipopt_options(warm=warm, **(ipopt or {})).items()}})
    return ocp, sym


class RockitMPC:
    """The belief MPC of ``horizon`` stages in rockit (module doc).

    ``solve`` sets ``s0``, the gates and references, the guess (controls)
    and its rollout (states) as the initial point, and solves; after a
    failed solve the last iterate is returned for the caller to check.
    """

    def __init__(self, kit: BeliefMPC, horizon: int, ipopt: dict | None = None, warm: bool = True) -> None:
        self.kit, self.N = kit, int(horizon)
        self.ocp, self.sym = rockit_ocp(kit, self.N, ipopt, warm)
        self.last_stats: dict = {}

    def _transcribed(self):
        """(opti, U, X) of rockit's transcription once it exists (after the
        first solve), else None; the initial values are then set on the
        transcribed ``casadi.Opti`` directly."""
        m = getattr(self.ocp, "_method", None)
        opti, U, X = (getattr(m, a, None) for a in ("opti", "U", "X"))
        if not isinstance(opti, ca.Opti) or not isinstance(U, list) or not isinstance(X, list) \
                or len(U) != self.N or len(X) != self.N + 1:
            return None
        return opti, U, X

    def solve(self, state: np.ndarray, t: int, steps: int, ref: np.ndarray, guess: np.ndarray,
              p: np.ndarray | None = None) -> np.ndarray:
        """Solve from ``state`` at time t of a run of ``steps`` (arguments as
        :meth:`.OptiMPC.solve`, ``p`` (n_p, N) each stage's obstacle data and
        levels); returns the planned inputs (nu, N)."""
        ocp, sym, kit = self.ocp, self.sym, self.kit
        if p is not None:
            ocp.set_value(sym["p"], np.asarray(p, float))
        ocp.set_value(sym["s0"], np.asarray(state, float))
        ocp.set_value(sym["gate"], kit.gates(t, self.N, steps))
        ocp.set_value(sym["ref"], np.asarray(ref, float))
        X = kit.rollout(state, guess)
        fast = self._transcribed()
        if fast is None:
            ocp.set_initial(sym["v"], ca.DM(guess))
            ocp.set_initial(sym["s"], ca.DM(X))
        else:      # rockit's set_initial re-hashes the whole problem per grid point (~85 ms a call)
            opti, U, Xs = fast
            for k in range(self.N):
                ca.Opti.set_initial(opti, U[k], guess[:, k])
            for k in range(self.N + 1):
                ca.Opti.set_initial(opti, Xs[k], X[:, k])
        try:
            sol = ocp.solve()
            self.converged = True
        except RuntimeError as exc:
            self.converged = False
            sol = ocp.non_converged_solution
            if sol is None:
                raise SolverError(f"rockit/IPOPT failed: {exc}") from exc
        self.last_stats = dict(sol.stats)
        if fast is not None and hasattr(sol, "sol"):
            V = np.asarray(sol.sol.value(ca.hcat(fast[1])), float).reshape(kit.nu, self.N)
        else:
            V = np.asarray(sol.sample(sym["v"], grid="control")[1], float)
            V = V.reshape(-1, kit.nu)[:self.N].T
        if not np.all(np.isfinite(V)):
            raise SolverError(f"rockit/IPOPT failed ({self.last_stats.get('return_status')})")
        return V
