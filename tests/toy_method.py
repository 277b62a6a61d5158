"""A toy smoothing method, written the way a user adds one: this single file.

"sensing_trim" scales all sensing down by a factor and the means toward the
straight chord between their neighbours, keeps a step when the shared exact
check passes and the cost falls, and halves its step size otherwise. Not a
good optimiser -- a different one, so the conformance suite sees a third kind.
"""

from __future__ import annotations

import numpy as np

from belief_nlp.smoother import IterationRecord, Method, Option, Outcome, register


def run(problem, *, shrink: float = 0.5, pull: float = 0.5) -> Outcome:
    model = problem.model
    z, cost = problem.start, problem.cost0
    for it in range(1, problem.max_iter + 1):
        if problem.out_of_time():
            return Outcome("time_limit", "out of time")
        cand = z.copy()
        cand.S[1:] *= 1 - shrink
        mid = 0.5 * (cand.x[:-2] + cand.x[2:])
        cand.x[1:-1] += pull * (mid - cand.x[1:-1])
        chk = problem.check(model.tighten(cand))
        c_new = model.cost(chk.point)[0] if chk.safe else np.inf
        ok = chk.safe and c_new < cost
        rec = IterationRecord(it, c_new if ok else cost, *model.cost(chk.point)[1:], "trimmed" if ok else "refused",
                              accepted=ok, min_margin=chk.margin)
        rel = (cost - c_new) / cost if ok else 0.0
        if ok:
            z, cost = chk.point, c_new
        else:
            shrink, pull = shrink / 2, pull / 2
        if problem.record(rec, z if ok else None):
            return Outcome("stopped" if problem.stop_requested else "time_limit", "stopped")
        if ok and rel < problem.tol or max(shrink, pull) < 1e-6:
            return Outcome("converged", f"no trim lowers the cost by more than tol after {it} iterations")
    return Outcome("max_iter", "iteration limit reached")


def _fraction(v):
    return None if isinstance(v, float) and 0 < v < 1 else "must be a float in (0, 1)"


METHOD = register(Method(name="sensing_trim", run=run, max_iter=30, description="toy: trim sensing, pull means",
                         options={"shrink": Option(0.5, "sensing scale-down per step", _fraction),
                                  "pull": Option(0.5, "pull of each mean toward its neighbours' midpoint",
                                                 _fraction)}),
                  replace=True)
