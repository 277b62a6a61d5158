"""The NLP solvers' iteration callback: history rows, candidate iterates, budget and stall stops."""

from __future__ import annotations

import heapq
import time

import casadi as ca
import numpy as np

from ..model.nlp_form import NLPProblem

__all__ = ["Recorder"]


class Recorder(ca.Callback):
    """Iteration callback of a CasADi nlpsol: history, best feasible iterates, progress.

    One recorder serves every attempt (restart) of a solve; ``begin`` resets
    the per-attempt counter and sets the parameter values."""

    def __init__(self, nlp: NLPProblem, keep: int, bar, stall: int = 0):
        ca.Callback.__init__(self)
        self.nlp = nlp
        self.nx = int(nlp.z.shape[0])
        self.ng = int(nlp.g.shape[0])
        self.keep = keep
        self.bar = bar
        self.calls = 0
        self.offset = 0
        self.pv = None
        self.budget = None
        self.deadline = None
        self.stop_reason = ""
        self.stall = stall
        self.log_path: str | None = None       # the solver's log file, if its backend writes one
        self.source_g = getattr(nlp, "source_g", None)
        self.best_cost = np.inf
        self.best_it = 0
        self.t_last = time.perf_counter()
        self.rows: list[tuple] = []            # (iteration, min margin, violation, dt, kalman gap, control, info)
        self.zs: list[np.ndarray] = []         # every iterate (candidates, keep_iterates)
        self.pvs: list[np.ndarray] = []        # the parameter of each attempt
        self.best: list[tuple] = []            # min-heap of (-objective, iteration, z): the lowest
        self.construct("belief_nlp_nlp_recorder", {})

    def reset(self, keep: int, bar, stall: int) -> None:
        """Forget a previous solve (the recorder lives as long as its solver)."""
        self.keep, self.bar, self.stall = keep, bar, stall
        self.calls = self.offset = 0
        self.rows, self.zs, self.pvs, self.best = [], [], [], []

    def begin(self, pv: np.ndarray, budget: int, deadline: float | None) -> None:
        """Start an attempt: parameter values, iteration budget and wall-clock
        deadline (the callback stops IPOPT at either; IPOPT then returns
        User_Requested_Stop and ``stop_reason`` says why)."""
        self.offset += max(self.calls - 1, 0)
        self.calls = 0
        self.pv = pv
        self.pv_dm = ca.DM(pv)
        self.pvs.append(pv)
        self.budget = budget
        self.deadline = deadline
        self.stop_reason = ""
        self.best_cost = np.inf
        self.best_it = 0
        self.t_last = time.perf_counter()

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        # only x, f and g are used; empty multipliers keep the per-iteration
        # conversion cheap (the callback was 20 % of the solve time otherwise)
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.dense(1)
        if name == "x":
            return ca.Sparsity.dense(self.nx)
        if name == "g":
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        it = self.calls
        self.calls += 1
        if it == 0:                # IPOPT's iteration 0 is the start point itself
            self.t_last = time.perf_counter()
            return [0]
        # x and g are dense (get_sparsity_in): their nonzeros are the vectors,
        # converted in a third of the time .full() takes (every iteration pays it);
        # the cost parts from x as it comes (a DM): converting the iterates
        # to a DM after the solve cost 4x more
        ctrl, info, _ = self.nlp.parts.call([arg[0], self.pv_dm])
        return [int(self._row(it + self.offset, np.array(arg[0].nonzeros()), np.array(arg[2].nonzeros()),
                              float(arg[1]), (float(ctrl), float(info))))]

    def solved(self, zv: np.ndarray, gv: np.ndarray, cost: float, stats: dict) -> None:
        """The end of a solve by a plug-in that never calls back (fatrop): its
        last point becomes the attempt's one record, numbered by the solver's
        own iteration count."""
        n_it = int(stats.get("iter_count", 0))
        self.calls = n_it + 1
        ctrl, info, _ = self.nlp.parts(zv, self.pv)
        self._row(self.offset + max(n_it, 1), zv, gv, cost, (float(ctrl), float(info)))
        if stats.get("success"):                # converged within the budget: no stop of ours
            self.stop_reason = ""

    def _row(self, it: int, zv: np.ndarray, gv: np.ndarray, cost: float, parts: tuple[float, float]) -> bool:
        """Record iterate ``it`` (objective incl. the tiny proximal term:
        ranks iterates; ``parts``: its control and information); True asks
        the solver to stop."""
        now = time.perf_counter()
        dt, self.t_last = now - self.t_last, now
        nlp = self.nlp
        viol = float(max(np.max(nlp.lbg - gv, initial=0.0), np.max(gv - nlp.ubg, initial=0.0)))
        if self.source_g is not None:           # a stage-ordered form: the source NLP's rows, in its order
            gv = self.source_g(gv)
        n_col, n_tgt = nlp.n_collision, nlp.info["n_target"]
        min_margin = float(min(np.min(gv[:n_col], initial=np.inf), np.min(gv[n_col:n_col + n_tgt], initial=np.inf)))
        kal = gv[n_col + n_tgt:n_col + n_tgt + nlp.info["n_kalman"]]
        # Kalman rows are entries of Q_k^-1 - Y_{k-1}^-1 - W in scaled units, where
        # ||Y^-1 + W|| >= ||W'|| = 1: the largest one is a relative gap
        kgap = float(np.max(np.abs(kal), initial=0.0))
        self.rows.append((it, min_margin, viol, dt, kgap, *parts))
        self.zs.append(zv)
        # candidates for the fallback: iterates feasible for the NLP
        feasible = viol <= 1e-6 and np.isfinite(cost)     # candidates; the exact check decides
        if feasible and cost < self.best_cost * (1 - 1e-7):
            self.best_cost, self.best_it = cost, self.calls - 1
        if feasible:
            item = (-cost, it, zv)
            if len(self.best) < self.keep:
                heapq.heappush(self.best, item)
            elif self.keep and item > self.best[0]:
                heapq.heapreplace(self.best, item)
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(cost=f"{cost:.5g}", viol=f"{viol:.1e}")
        if self.budget is not None and self.calls - 1 >= self.budget:
            self.stop_reason = "max_iter"
            return True
        if self.deadline is not None and now > self.deadline:
            self.stop_reason = "time_limit"
            return True
        if self.stall and feasible and self.calls - 1 - self.best_it >= self.stall:
            # feasible, but no feasible iterate has lowered the cost for `stall`
            # iterations: IPOPT is creeping (seen as long runs of tiny steps and
            # watchdog trials next to an optimum); stop so a restart can finish
            self.stop_reason = "stalled"
            return True
        return False
