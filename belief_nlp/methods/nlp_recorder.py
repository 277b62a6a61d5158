"""The NLP solvers' iteration callback: history rows, candidate iterates, budget and stall stops."""

from __future__ import annotations

import heapq
import time

import casadi as ca
import numpy as np

from ..model.nlp_form import NLPProblem

__all__ = ["Recorder"]

_MAX, _MIN = np.maximum.reduce, np.minimum.reduce

#: an iterate with a lifted factor |M_ij| above RUNAWAY sqrt((W^-1)_ii) ends the
#: attempt (Q_k a hundredfold beyond any Kalman-feasible point): on paper-multi and
#: random-polygons (K = 20, 40) no iterate passed 1.05; on tutorial at confidence
#: 0.99-0.999 the runs that failed passed 65-2e6 (docs/numerics.md, "The Kalman box")
RUNAWAY = 10.0

#: an attempt whose iterates violate the rows by more than WALK_VIOLATION (scaled
#: units) for WALK consecutive iterations ends too, as a runaway does ("walked"):
#: on the issue-21 protocol (K = 20 / 40 / 80, 104 first stages, all converged) the
#: longest such run was 14 iterations; an attempt at K = 40 that wandered through
#: restoration for 483 iterations (random-polygons map 5, alpha 0.1, then converging
#: in 92 inside the box) had 254 (docs/numerics.md, "The first stage's barrier floor")
WALK, WALK_VIOLATION = 50, 10.0

#: a polish (a stage told to ``probe``) whose iterate PROBE still violates the rows by
#: more than PROBE_VIOLATION (scaled units) ends there ("far"): on the issue-21
#: protocol (184 polishes per method) none that converged was above it there (the
#: closest: 0.012 one iterate later, converged at 45), and the 7 at K = 80 that ran to
#: their cap of 50 without an answer were all above it (0.027-8.3 one iterate later,
#: six above 0.15); the step-down that follows them starts 30 iterations earlier
#: (docs/numerics.md, "A polish far from feasible")
PROBE, PROBE_VIOLATION = 20, 0.05


class Recorder(ca.Callback):
    """Iteration callback of a CasADi nlpsol: history, best feasible iterates, progress.

    One recorder serves every attempt (restart) of a solve; ``begin`` resets
    the per-attempt counter and sets the parameter values."""

    #: keep every iterate in ``zs`` (tests compare the rows with them); off,
    #: a recorder holds only its ``keep`` best candidates: every iterate of a
    #: K = 80 solve is tens of MB, held as long as the cached solver
    keep_all_iterates = False

    def __init__(self, nlp: NLPProblem, keep: int, bar, stall: int = 0, pad: int = 0):
        ca.Callback.__init__(self)
        self.n = int(nlp.z.shape[0])
        self.nx = self.n + int(pad)            # the solver's x: the NLP's and its padding (nlp_padded)
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
        self.runaway = False                   # stop an iterate far outside the Kalman box (reset)
        self.probe = False                     # stop at iterate PROBE when still far from feasible (reset)
        self.walk = 0                          # consecutive iterates violating the rows by > WALK_VIOLATION
        self.log_path: str | None = None       # the solver's log file, if its backend writes one
        self.best_cost = np.inf
        self.best_it = 0
        self.t_last = time.perf_counter()
        self.rows: list[tuple] = []            # (iteration, min margin, violation, dt, kalman gap, control, info)
        self.zs: list[np.ndarray] = []         # every iterate, only with keep_all_iterates (tests)
        self.pvs: list[np.ndarray] = []        # the parameter of each attempt
        self.best: list[tuple] = []            # min-heap of (-objective, iteration, z): the lowest
        self.nlp = None
        self.bind(nlp)
        self.construct("belief_nlp_nlp_recorder", {})

    def bind(self, nlp: NLPProblem) -> None:
        """Read the iterates as ``nlp``'s (the solver's NLP, or a form on
        the same variables and rows: :func:`belief_nlp.model.nlp_prefix.frozen`):
        its row bounds, its rows (``source_g``) and its cost parts."""
        if nlp is self.nlp:
            return
        self.nlp = nlp
        self.source_g = getattr(nlp, "source_g", None)
        # the cost parts evaluated in place (numpy buffers, no DM per iteration);
        # the same function as ``nlp.parts``, so the same values to the last bit
        self._parts_buf, self._parts_run = nlp.parts.buffer()
        # (control, information, regulariser); the buffer holds raw pointers: the arrays live as long as it
        self._parts_out = [np.zeros(nlp.parts.nnz_out(i)) for i in range(3)]
        for i, out in enumerate(self._parts_out):
            self._parts_buf.set_res(i, memoryview(out))
        if self.pv is not None:
            self._parts_buf.set_arg(1, memoryview(self.pv))
        # the free entries of the lifted factors M_k and RUNAWAY times their Kalman box
        # (NLPProblem.kalman_box; M is never scaled, nlp_scaled; a stage-ordered form has none)
        _, ub = nlp.kalman_box(nlp.lbz, nlp.ubz) if nlp.has_kalman_box else (None, nlp.ubz)
        self._m = np.flatnonzero(ub < nlp.ubz)
        self._m_limit = RUNAWAY * ub[self._m]

    def reset(self, keep: int, bar, stall: int, runaway: bool = False, probe: bool = False) -> None:
        """Forget a previous solve (the recorder lives as long as its solver);
        ``runaway``: stop an attempt whose iterate leaves the Kalman box by
        the factor RUNAWAY (then ``stop_reason`` is "left_box") or whose
        iterates stay infeasible by WALK_VIOLATION for WALK iterations
        ("walked"); ``probe``: stop an attempt whose iterate PROBE violates
        the rows by more than PROBE_VIOLATION ("far")."""
        self.keep, self.bar, self.stall, self.runaway, self.probe = keep, bar, stall, runaway, probe
        self.calls = self.offset = 0
        self.rows, self.zs, self.pvs, self.best = [], [], [], []

    def begin(self, pv: np.ndarray, budget: int, deadline: float | None) -> None:
        """Start an attempt: parameter values, iteration budget and wall-clock
        deadline (the callback stops IPOPT at either; IPOPT then returns
        User_Requested_Stop and ``stop_reason`` says why)."""
        self.offset += max(self.calls - 1, 0)
        self.calls = 0
        self.pv = np.ascontiguousarray(pv, dtype=float)
        self._parts_buf.set_arg(1, memoryview(self.pv))
        self.pvs.append(pv)
        self.budget = budget
        self.deadline = deadline
        self.stop_reason = ""
        self.best_cost = np.inf
        self.best_it = 0
        self.walk = 0
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

    def has_eval_buffer(self) -> bool:
        """CasADi hands :meth:`eval_buffer` the solver's own buffers."""
        return True

    def eval_buffer(self, arg, res) -> int:
        """One iteration from the nlpsol: x, f and g as memoryviews of the
        solver's buffers (no DM per input and iteration: the DM route cost
        ~0.25-0.45 ms an iteration, a fifth of IPOPT's own time per iteration
        at K = 20); x is copied (candidates keep it), g only read here."""
        x = np.array(np.frombuffer(arg[0], dtype=np.float64)[:self.n])
        if arg[1] is None or arg[2] is None:
            # a solver that passes f and g as NULL (CasADi's Uno plug-in): the
            # NLP's own values at x, or the history and the candidates would
            # read zeros (every collision row short of its margin)
            f, g = self._fg(x)
        else:
            f, g = float(np.frombuffer(arg[1], dtype=np.float64)[0]), np.frombuffer(arg[2], dtype=np.float64)
        stop = self._take(x, f, g)
        if res[0] is not None:
            np.frombuffer(res[0], dtype=np.float64)[0] = float(stop)
        return 0

    def _fg(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """Objective and rows at x with the attempt's parameter."""
        f, g = self.nlp.fg(x, self.pv)
        return float(f), np.asarray(g, float).ravel()

    def eval(self, arg):
        """One iteration given as DMs (x, f, g): backends outside CasADi call this."""
        # x and g are dense (get_sparsity_in): their nonzeros are the vectors
        return [int(self._take(np.array(arg[0].nonzeros()), float(arg[1]), np.array(arg[2].nonzeros())))]

    def _take(self, zv: np.ndarray, cost: float, gv: np.ndarray) -> bool:
        """Count an iteration and record it (IPOPT's iteration 0, the start
        point itself, is not recorded); True asks the solver to stop."""
        it = self.calls
        self.calls += 1
        if it == 0:
            self.t_last = time.perf_counter()
            return False
        # the cost parts from x as it comes: converting the iterates after the solve cost 4x more
        self._parts_buf.set_arg(0, memoryview(zv))
        self._parts_run()
        ctrl, info = (float(o[0]) if o.size else 0.0 for o in self._parts_out[:2])
        return self._row(it + self.offset, zv, gv, cost, (ctrl, info))

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
        # the ufuncs' reduce is what np.max / np.min call, without their Python
        # wrapper (5 reductions an iteration)
        viol = float(max(_MAX(nlp.lbg - gv, initial=0.0), _MAX(gv - nlp.ubg, initial=0.0)))
        if self.source_g is not None:           # a stage-ordered form: the source NLP's rows, in its order
            gv = self.source_g(gv)
        n_col, n_tgt = nlp.n_collision, nlp.info["n_target"]
        min_margin = float(min(_MIN(gv[:n_col], initial=np.inf), _MIN(gv[n_col:n_col + n_tgt], initial=np.inf)))
        kal = gv[n_col + n_tgt:n_col + n_tgt + nlp.info["n_kalman"]]
        # Kalman rows are entries of Q_k^-1 - Y_{k-1}^-1 - W in scaled units, where
        # ||Y^-1 + W|| >= ||W'|| = 1: the largest one is a relative gap
        kgap = float(_MAX(np.abs(kal), initial=0.0))
        self.rows.append((it, min_margin, viol, dt, kgap, *parts))
        if self.keep_all_iterates:
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
        if self.runaway and bool((np.abs(zv[self._m]) > self._m_limit).any()):
            # prior information a hundredfold beyond any Kalman-feasible point: the
            # runaway that ended in Infeasible_Problem_Detected or Invalid_Number_Detected
            # hundreds of iterations later; stop so a restart inside the box can solve
            self.stop_reason = "left_box"
            return True
        if self.probe and self.calls - 1 == PROBE and viol > PROBE_VIOLATION:
            # a polish this far from feasible this late has not converged in its cap
            # (PROBE's measurements); the caller's step-down follows sooner
            self.stop_reason = "far"
            return True
        self.walk = self.walk + 1 if viol > WALK_VIOLATION else 0
        if self.runaway and self.walk >= WALK:
            # far from feasible for WALK iterations (seen: hundreds of restoration
            # iterations before converging or failing); a restart inside the box finishes
            self.stop_reason = "walked"
            return True
        if self.stall and feasible and self.calls - 1 - self.best_it >= self.stall:
            # feasible, but no feasible iterate has lowered the cost for `stall`
            # iterations: IPOPT is creeping (seen as long runs of tiny steps and
            # watchdog trials next to an optimum); stop so a restart can finish
            self.stop_reason = "stalled"
            return True
        return False
