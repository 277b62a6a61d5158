"""What one NLP stage ended with (:class:`Stage`), the exactly safe points
among a solve's candidates, the history records of an attempt, and the
run's outcome from its stages: the parts of :mod:`.nlp_engine` that read a
solve's results rather than run it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..model import Layout
from ..model.nlp_form import NLPProblem
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.result import STATUSES, IterationRecord
from .nlp_backend import NLPBackend
from .nlp_recorder import Recorder

__all__ = ["Stage", "STOPS", "safe_points", "record_attempt", "outcome", "still_lowering"]


def safe_points(problem: SmoothingProblem, nlp: NLPProblem, recorder: Recorder, z_end: np.ndarray | None,
                 converged: bool) -> list[tuple[float, Layout, str, int | None]]:
    """Exactly safe points among the solver's last point and the recorded feasible
    iterates, as (cost, point, description, iteration or None for the last
    point); when the solver converged and its last point is safe, that point alone."""
    pool = [(None, z_end)] if z_end is not None and np.all(np.isfinite(z_end)) else []
    pool += [(it, zv) for _, it, zv in recorder.best]
    found = []
    for it, zv in pool:
        try:
            chk = problem.check(problem.model.tighten(nlp.unpack(zv)))
        except np.linalg.LinAlgError:
            continue
        if not chk.safe and it is None:
            # the last point of an unconverged run often sits ~1e-6 outside
            # (a polish next to a constraint it cannot quite meet): the
            # shared repair adds a little sensing when that makes it safe
            chk = problem.repair(chk) or chk
        if not chk.safe:
            continue
        where = "the solver's final point" if it is None else f"iterate {it} (the best feasible one)"
        found.append((problem.model.cost(chk.point)[0], chk.point, where, it))
        if it is None and converged:
            return found
    return found


def record_attempt(problem: SmoothingProblem, nlp: NLPProblem, recorder: Recorder, start: int,
                    found: list, raw_status: str) -> None:
    """History records of one attempt's iterations (cost parts from the recorder)."""
    rows = recorder.rows[start:]
    if not rows:
        return
    D = problem.model.data
    safe = {it: z for _, z, _, it in found if it is not None}
    last = rows[-1][0]
    final = next((z for _, z, _, it in found if it is None), None)
    for it, mmin, viol, dt, kgap, ctrl, info in rows:
        rec = IterationRecord(it, float(ctrl + D.alpha * info), float(ctrl), float(info),
                              raw_status if it == last else "", dt, 0.0, dt, 1, accepted=viol <= 1e-6,
                              min_margin=mmin, kalman_gap=kgap)
        point = final if it == last and final is not None else safe.get(it)
        problem.record(rec, point if rec.accepted else None)


@dataclass
class Stage:
    """What one NLP stage (one formulation, its attempts) ended with."""

    status: str = "not run"              # the solver's own last return status
    used: int = 0
    answer: tuple | None = None          # (cost, point, where, None): converged and exactly safe
    best: tuple | None = None            # lowest-cost exactly safe point seen (cost, point, where)
    attempts: list = field(default_factory=list)
    build: str = ""
    build_time: float = 0.0
    limit: int = 0                       # the stage's iteration limit
    duals: tuple | None = None           # (lam_x, lam_g) of the answer's solve (backends with warm_duals)
    z: np.ndarray | None = None          # the variables of that solve (with duals)
    solved: tuple | None = None          # (nlp, solver, p) of that solve

    def absorb(self, more: "Stage", take: bool) -> None:
        """``more``, a later solve that continues this stage, merged in: its
        attempts, iterations and build time; with ``take`` its answer, its
        variables, multipliers and solve, and its status (also its status
        when this stage has no answer); its best point when lower."""
        self.attempts += more.attempts
        self.used += more.used
        self.build_time += more.build_time
        if take:
            self.answer, self.z, self.duals, self.solved = more.answer, more.z, more.duals, more.solved
        if take or self.answer is None:
            self.status = more.status
        if more.best is not None and (self.best is None or more.best[0] < self.best[0]):
            self.best = more.best


STOPS = {"max_iter": "Maximum_Iterations_Exceeded", "time_limit": "Maximum_WallTime_Exceeded", "stalled": "Stalled",
          "left_box": "Left_Kalman_Box", "walked": "Infeasible_Walk", "far": "Far_From_Feasible"}


#: a polish at its cap whose cost fell by more than POLISH_LOWERING (relative) over
#: its last POLISH_TAIL iterations gets one more run of its cap from where it stopped
#: (its variables, multipliers and switched-off sensing). Seen: a polish walking the
#: means after a first stage at mu_min 3e-6 (notebook 03's case: 67 iterations to
#: converge, 2.31369 at the cap of 50 against 2.31283); a polish creeping at its
#: answer lowers its cost by < 1e-7 there (docs/numerics.md, "The first stage's
#: barrier floor", the polish's cap)
POLISH_TAIL, POLISH_LOWERING = 10, 1e-5


def still_lowering(problem: SmoothingProblem, polish: Stage, cap: int) -> bool:
    """``polish`` stopped at its own cap while its cost was still falling
    (the history's last POLISH_TAIL records, feasible or not)."""
    if polish.status != STOPS["max_iter"] or polish.used < cap or polish.z is None or polish.duals is None:
        return False
    costs = [r.cost for r in problem.history[-polish.used:]]
    if len(costs) <= POLISH_TAIL:
        return False
    before, now = costs[-POLISH_TAIL - 1], costs[-1]
    return bool(np.isfinite(before) and np.isfinite(now) and before - now > POLISH_LOWERING * abs(now))


def outcome(problem: SmoothingProblem, backend: NLPBackend, stages: list[Stage], max_iter: int) -> Outcome:
    """The run's status, answer and raw stats from its stages (``max_iter``:
    the run's iteration limit, the method's or a lower ``max_iter`` solver option)."""
    first, last = stages[0], stages[-1]
    attempts = [a for s in stages for a in s.attempts]
    stats: dict[str, Any] = {
        "iteration_limit": int(max_iter),
        "build": first.build, "build_time": sum(s.build_time for s in stages), "attempts": attempts,
        "return_status": first.status, "iter_count": sum(s.used for s in stages),
        "restoration": None if any(a["restoration"] is None for a in attempts)
        else sum(a["restoration"] for a in attempts),
        "cpu_time": sum(a["cpu_time"] for a in attempts)}
    status = backend.map_status(first.status)
    message = f"{backend.name} returned {first.status} after {first.used} iterations"
    if len(first.attempts) > 1:
        message += f" in {len(first.attempts)} attempts ({', '.join(a['return_status'] for a in first.attempts)})"
    elif first.status == STOPS["max_iter"] and first.used < first.limit:
        # the first attempt gets two thirds of the limit; the rest is for a
        # restart from a safe point below the start, and there was none
        message += (f", the first attempt's share of the iteration limit {first.limit}: the rest "
                    f"({first.limit - first.used}) is kept for a restart from an exactly safe iterate below the "
                    f"warm start, and there was none")
    answer = first.answer
    if len(stages) > 1:
        stats["polish_status"] = last.status
        if last.answer is not None and last.answer[0] <= first.answer[0]:
            answer = last.answer
            message += f"; polished on the exact Cholesky NLP in {last.used} iterations"
        elif last.best is not None and last.best[0] < first.answer[0]:
            # unconverged (often ~1e-6 short of an equality it cannot quite
            # meet), yet an exactly safe point below stage 1's answer
            answer = (*last.best, None)
            message += (f"; polish ended {last.status} after {last.used} iterations, its best exactly safe point "
                        f"({last.best[2]}) is used")
        else:
            message += f"; polish ended {last.status} after {last.used} iterations (not lower; not used)"
    if status == "converged" and answer is None:
        status = "infeasible_iterate"
        message += f"; its last point failed the exact safety check ({STATUSES[status]})"
    elif status != "converged":
        message += f" ({STATUSES[status]})"
    if problem.stop_requested and status != "converged":
        status, message = "stopped", STATUSES["stopped"]
    return Outcome(status, message, answer[1] if answer else None, backend.name, stats)
