"""The shared engine of the NLP methods (CasADi ``nlpsol`` plug-ins): one
:class:`~.nlp_backend.NLPBackend` per solver file (``ipopt.py``, ``sqp.py``,
``fatrop.py``) says how to build the solver's options and read its statuses;
the NLP and solver instances come from :mod:`.nlp_build` (memory and disk
caches), the iteration callback is :mod:`.nlp_recorder`; everything else --
the two stages, the restarts, the exact safety check of every candidate,
the history and the raw stats -- is here, the same for every solver.

Stages (docs/numerics.md, "IPOPT iterations"):

1. the "logchol" NLP: S_k = L_k L_k^T with L_k,ii = exp(w) >= ``floor`` keeps
   the iterates off the L = 0 saddle, where every gradient in L vanishes and
   a minimal-sensing warm start sits;
2. a polish of at most ``polish`` iterations on the exact "cholesky" NLP from
   that answer, with the sensing directions held at the floor switched off
   (:meth:`~belief_nlp.model.nlp_form.NLPProblem.without_sensing`), and --
   for backends with ``warm_duals`` (IPOPT) -- from stage 1's multipliers
   (the same graph, so the same rows and variables); its answer replaces
   stage 1's when it converged, is exactly safe and is not costlier;
3. for backends with ``warm_duals``, at most ``reenter`` rounds of the polish
   that turn one switched-off column back on where the answer's Hessian
   block says sensing lowers the cost (:mod:`.nlp_reentry`; not on a re-plan's
   longer graph with frozen steps);
4. for backends with ``warm_duals``, after a polish without an answer or
   one whose switched-off sensing still pays after the rounds, the floored
   stage once more at ``floor * step_down`` from its answer and
   multipliers, then the polish at that floor (:mod:`.nlp_stepdown`; not on
   a frozen graph); with a step-down to follow, a polish whose iterate
   :data:`.nlp_recorder.PROBE` still violates the rows by more than
   ``PROBE_VIOLATION`` ends there (status "Far_From_Feasible").

A re-plan with the option ``resume`` (:mod:`.nlp_resume`) first resumes
the polish alone from the earlier polish's answer and multipliers, when that
answer was the run's (its switched-off sensing stays off: a loop's re-plan
keeps the sensing pattern while this converges); when it does not end
converged and exactly safe, the first stage resumes from its own earlier
state and the polish follows; when that fails too, the usual first stage
runs from the warm start. A backend without ``warm_duals`` (fatrop, Uno)
keeps a state of the graph alone: its re-plan after executed steps runs the
usual stages from the warm start on that graph, the steps frozen, so
nothing is built.

When a stage stops without converging (iteration share, solver failure, a
stall of ``stall`` iterations without a lower feasible cost), the solver is
restarted from the best exactly safe point so far. For a backend with
``kalman_box`` (IPOPT) the restart runs inside the Kalman box
(:meth:`~belief_nlp.model.nlp_form.NLPProblem.kalman_box`: bounds every
Kalman-feasible point satisfies; docs/numerics.md, "The Kalman box") when
there is no such point below the stage's start, when an iterate left the box
tenfold (a lifted factor |M_ij| > 10 sqrt((W^-1)_ii): the recorder stops it,
status "Left_Kalman_Box") or its iterates stayed infeasible by more than 10
for 50 iterations (status "Infeasible_Walk", nlp_recorder.WALK), or when the
stage converged above its start. A
backend with ``stage_options["rescue"]`` (Uno: funnel-SQP; fatrop: mu_init
1e-3, its one restart) restarts from the start with those options when
nothing safe was found below it. The solver's last point is the answer when
it converged and the point is exactly safe (the lower one when both attempts
converged); otherwise the best exactly safe recorded iterate is (the
driver's rule).

History: one record per solver iteration (stages and restarts continue the
numbering; IPOPT calls back once more than it counts when it enters its
restoration phase, so its ``iter_count`` can be below the records) with
its cost parts; ``accepted`` = satisfies the NLP's constraints to
1e-6; ``min_margin`` = the smallest NLP margin; ``kalman_gap`` = the largest
Kalman-equality residual. Stats: ``attempts`` (formulation, return status,
iterations, restoration iterations, CPU and wall seconds), ``iter_count``,
``restoration``, ``cpu_time``, ``return_status``, ``polish_status``,
``resumed`` (with the option ``resume``: "yes", "fell back" when that solve
did not end converged and exactly safe and the usual first stage ran,
"graph" when a state without multipliers gave the graph the usual stages
ran on, "does not fit" when it cannot be used here: another graph, plug-in,
floor, formulation or ``scale_means``, or a prefix that cannot be frozen at
this start; "no" without it), ``resumed_stage``
("polish" or "first": which resumed stage answered; None otherwise),
``polish_skipped`` (a re-plan after one whose polish did not lower its
answer skips it, ``polish_retry`` times: :data:`POLISH_RETRY`),
``sensing_stationary`` (the polish's answer is stationary for the sensing
it switched off, :mod:`.nlp_stationary`; None when no polish answered),
``sensing_reentered`` (the rounds of :mod:`.nlp_reentry` whose answer was taken),
``floor_stepped_down`` (:func:`.nlp_stepdown.step_down`'s outcome; None when it did not run).
"""

from __future__ import annotations

import logging
import os
import re
import time
from typing import Any, Callable

import numpy as np

from ..errors import ValidationError
from ..model import Layout
from ..model.nlp_form import NLPProblem
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.policy import DEFAULT_POLICY
from ..smoother.result import STATUSES
from .nlp_backend import NLPBackend, solver_stats
from . import nlp_reentry, nlp_resume, nlp_stepdown
from ..model.nlp_prefix import longer
from .nlp_build import _CACHE, _GRAPHS, _base_key, clear_cache, solver_of  # noqa: F401 - _CACHE, _GRAPHS, clear_cache: re-exported
from .nlp_options import POLISH_RETRY, REENTER, STEP_DOWN, nlp_options  # noqa: F401 - nlp_options: re-exported
from .nlp_recorder import Recorder
from .nlp_stage import STOPS, Stage, outcome, record_attempt, safe_points, still_lowering
from .nlp_stationary import sensing_stationary

__all__ = ["NLPBackend", "run_nlp", "clear_cache", "nlp_options"]

log = logging.getLogger("belief_nlp.smoother")


def _log_size(log_path: str | None) -> int:
    try:
        return os.path.getsize(log_path) if log_path else 0
    except OSError:
        return 0


#: iterations per step a first stage resumed from an earlier answer may take
#: (it took 4-9 on paper-multi at K = 20 and 65-167 at K = 80, where a fixed
#: cap of 100 sent 2 of 4 re-plans back to a cold stage of 170-270
#: iterations); past them the usual first stage runs instead
RESUME_LIMIT = 5

def _solve_stage(problem: SmoothingProblem, backend: NLPBackend, stage: Stage, *, formulation: str, opts: dict,
                 margin: float, regularisation: float, floor: float, candidates: int, cache: bool, start: Layout,
                 max_iter: int, restarts: int, stall: int, offset: int, bar: Any,
                 bounds: Callable | None = None, duals: tuple | None = None, scale: float = 1.0,
                 prefix: int = 0, rescue: dict | None = None, probe: bool = False) -> Stage:
    """The solver on one formulation from ``start``: attempts with restarts
    from the best exactly safe point (module doc), at most ``max_iter``
    iterations. ``bounds(nlp, point)`` -> (z0, lbz, ubz) replaces the NLP's
    own start and bounds; ``duals`` (lam_x, lam_g) are the first attempt's
    initial multipliers (a restart starts without them); ``scale`` != 1: the
    NLP with its means scaled (:mod:`.nlp_scaled`; the stage's ``duals`` are
    then the unscaled NLP's); ``rescue``: the plug-in's options of a restart
    from the start when nothing safe was found below it (``stage_options["rescue"]``);
    ``probe``: the recorder's stop of an attempt still far from feasible at
    its iteration PROBE (:data:`.nlp_recorder.PROBE`)."""
    if not backend.calls_back:
        # fatrop's limit m allows m + 1 iterations by its own count (measured); no
        # callback records a point to restart from: only its rescue restarts it
        opts, restarts = {**opts, backend.limit_key: max(int(max_iter) - 1, 0)}, int(rescue is not None)
    t_build = time.perf_counter()
    nlp, solver, recorder, stage.build = solver_of(problem.model, backend, opts, formulation, margin, regularisation,
                                                   floor, max(int(candidates), 0), cache, scale, prefix)
    stage.build_time = time.perf_counter() - t_build
    stage.limit = int(max_iter)
    can_box = backend.kalman_box and nlp.has_kalman_box
    recorder.reset(keep=max(int(candidates), 0), bar=bar, stall=stall if restarts else 0,
                   runaway=bool(restarts) and can_box, probe=probe)
    recorder.offset = offset
    z_start = start
    stage.best = (problem.model.cost(start)[0], start, "the stage's start")
    start_cost = stage.best[0]
    n_attempts, boxed, above = 0, False, None
    while True:
        remaining = max_iter - stage.used
        budget = remaining if n_attempts >= restarts else max(1, remaining - remaining // 3)
        if problem.out_of_time() or remaining <= 0:
            stage.status = STOPS["time_limit" if problem.out_of_time() else "max_iter"]
            break
        pv = nlp.anchor(z_start, problem.model.data.alpha)
        n_rows = len(recorder.rows)
        recorder.begin(pv, budget, problem.deadline)
        t_solve, c_solve, log_at = time.perf_counter(), time.process_time(), _log_size(recorder.log_path)
        try:
            x0, lbx, ubx = bounds(nlp, z_start) if bounds else (nlp.pack(z_start), nlp.lbz, nlp.ubz)
            if boxed:
                lbx, ubx = nlp.kalman_box(lbx, ubx)
            warm = {}
            if duals is not None and n_attempts == 0:
                # a row without bounds (a frozen step's, nlp_prefix) starts without a multiplier
                bounded = np.isfinite(nlp.lbg) | np.isfinite(nlp.ubg)
                warm = {"lam_x0": duals[0], "lam_g0": np.where(bounded, duals[1], 0.0)}
            problem.solver_started()        # built: what may overlap the solve starts now
            sol, st, ended = backend.solve(
                solver, dict(x0=x0, p=pv, lbx=lbx, ubx=ubx, lbg=nlp.lbg, ubg=nlp.ubg, **warm), problem.deadline)
            recorder.stop_reason = ended or recorder.stop_reason     # ended from outside (fatrop's watchdog)
            z_end = None if sol is None else np.asarray(sol["x"]).ravel()
            if backend.warm_duals and sol is not None:
                stage.duals = (np.asarray(sol["lam_x"]).ravel() / nlp.info.get("variable_scale", 1.0),
                               np.asarray(sol["lam_g"]).ravel())
                stage.z, stage.solved = z_end, (nlp, solver, pv)
            if not backend.calls_back and sol is not None:
                recorder.solved(z_end, np.asarray(sol["g"]).ravel(), float(np.asarray(sol["f"]).flat[0]), st)
        except RuntimeError as exc:   # CasADi raises on some solver exceptions
            log.warning("%s raised: %s", backend.name, exc)
            z_end, st = None, solver_stats(solver)
        raw = STOPS[recorder.stop_reason] if recorder.stop_reason else backend.return_status(st)
        why = backend.refused(raw, opts, recorder.log_path, log_at)
        if why:
            raise ValidationError("solver_options", why)
        stage.status = raw
        n_it = _iterations(st, recorder, backend)
        stage.attempts.append({"formulation": formulation, "return_status": raw, "iter_count": n_it,
                               "restoration": backend.restoration(st, recorder.log_path, log_at),
                               "wall_time": time.perf_counter() - t_solve,
                               "cpu_time": time.process_time() - c_solve + st.get("child_cpu_time", 0.0),
                               **backend.attempt_stats(st)})
        stage.used += n_it
        if z_end is None and not backend.calls_back:      # no record says how far it got
            problem.unrecorded_to = max(problem.unrecorded_to, offset + stage.used)
        n_attempts += 1
        status = backend.map_status(raw)
        found = safe_points(problem, nlp, recorder, z_end, status == "converged")
        record_attempt(problem, nlp, recorder, n_rows, found, raw)
        if status == "converged" and found and found[0][3] is None:
            if boxed or not can_box or found[0][0] <= start_cost:
                stage.answer = found[0] if above is None or found[0][0] <= above[0][0] else above[0]
                break
            above = (found[0], raw)    # a stationary point costlier than the start: kept, and one more try
        for cand in found:
            if cand[0] < stage.best[0]:
                stage.best = cand[:3]
        if n_attempts > restarts or status == "time_limit" or stage.used >= max_iter or problem.stop_requested:
            break
        how, new_opts = "", None
        if stage.best[1] is z_start or recorder.stop_reason in ("left_box", "walked"):
            # nothing safe below the start, or a runaway: again inside the Kalman box (docs/numerics.md,
            # "The Kalman box"), or with the plug-in's rescue options; else the stage ends
            if can_box and not boxed:
                boxed, how = True, " inside the Kalman box"
            elif rescue is not None and rescue != opts:
                new_opts, rescue, how = rescue, None, " with its rescue options"
            else:
                break
        if not backend.calls_back:           # its own limit: what is left of the stage's
            if max_iter - stage.used < 2:
                break
            new_opts = {**(new_opts or opts), backend.limit_key: max_iter - stage.used - 1}
        if new_opts is not None:             # another solver; numbered on from the last record
            opts = new_opts
            calls, t_build = (recorder.rows[-1][0] if recorder.rows else recorder.offset), time.perf_counter()
            nlp, solver, recorder, _ = solver_of(problem.model, backend, opts, formulation, margin, regularisation,
                                                 floor, max(int(candidates), 0), cache, scale, prefix)
            stage.build_time += time.perf_counter() - t_build
            recorder.reset(keep=max(int(candidates), 0), bar=bar, stall=stall)
            recorder.offset = calls
        log.info("%s %s after %d iterations; restarting from %s%s", backend.name, raw, stage.used, stage.best[2], how)
        z_start = stage.best[1]
    if stage.answer is None and above is not None:
        stage.answer, stage.status = above
    return stage


def _iterations(stats: dict, recorder: Recorder, backend: NLPBackend) -> int:
    """The solver's iteration count of the last solve. A solver that stopped
    before its first iteration can report an uninitialised count (IPOPT
    through CasADi after Invalid_Option: 1,826,456,736, -103,725,968 or 89
    measured); a plug-in that calls back is called once per iteration, so
    a count its callbacks cannot account for is replaced by theirs."""
    counted = max(recorder.calls - 1, 0)
    try:
        n = int(stats.get("iter_count", counted))
    except (TypeError, ValueError):
        return counted
    if backend.calls_back and not 0 <= n <= recorder.calls:
        return counted
    return max(n, 0)


def run_nlp(problem: SmoothingProblem, backend: NLPBackend, *, formulation: str = "logchol", floor: float = 1e-2,
            polish: int = 50, regularisation: float = 1e-4, margin: float = DEFAULT_POLICY.nlp, restarts: int = 1,
            stall: int = 300, candidates: int = 5, cache: bool = True, scale_means: float = 1.0,
            resume: dict | None = None, polish_retry: int = POLISH_RETRY,
            first_stage_options: dict | None = None, reenter: int = REENTER,
            step_down: float = STEP_DOWN) -> Outcome:
    """``backend``'s solver from the problem's start (module doc); ``scale_means``
    != 1 solves the first stage with the means scaled (:mod:`.nlp_scaled`);
    ``resume``: an earlier answer's first-stage state (:mod:`.nlp_resume`),
    the first stage's start when it fits (same graph, plug-in and floor) --
    and the usual first stage from the warm start when that solve does not
    end converged and exactly safe. ``first_stage_options``: the plug-in's
    options of the first stage's attempts only, over the run's."""
    if problem.model.data.alpha == 0:
        # measured: IPOPT stopped on NaN (Invalid_Number_Detected) after 180 iterations, twice
        raise ValidationError("alpha", f"must be > 0 for {backend.name}: with alpha = 0 sensing costs nothing and "
                                       "the NLP has no minimiser (its sensing grows without bound); methods "
                                       "'auto' and 'ccp' answer alpha = 0 with CCP")
    if problem.out_of_time():                      # the warm start used the budget up
        return Outcome("time_limit", f"{STATUSES['time_limit']} (before {backend.name} started)", None,
                       backend.name)
    # the first stage's own solver options go over the run's in all its attempts (the polish keeps the run's)
    first_opts = {**problem.solver_options, **(first_stage_options or {})}
    opts = backend.options(first_opts, problem.tol, formulation)
    checks = [("solver_options", problem.solver_options)] + ([("first_stage_options", first_opts)]
                                                             if first_stage_options else [])
    for field, checked in checks:
        bad = backend.check_options(backend.options(checked, problem.tol, formulation))
        if bad:
            raise ValidationError(field, bad)
    rescue_opts = backend.options(first_opts, problem.tol, "rescue") \
        if "rescue" in backend.stage_options and formulation == "logchol" else None
    # the plug-in's own limit is set out of reach (a constant keeps the cache
    # key stable); the recorder enforces the run's budget; a user's
    # "max_iter" solver option still caps it
    max_iter = min(int(opts.get(backend.limit_key, problem.max_iter)), problem.max_iter)
    bar = problem.progress_bar(backend.name)
    common = dict(margin=margin, regularisation=regularisation, candidates=candidates, cache=cache, bar=bar,
                  stall=stall)
    # a state of the graph (the scenario and K) this run solves; its variables and
    # multipliers a start only for a solver that takes initial multipliers
    graphed = formulation == "logchol" and scale_means == 1
    resumable = backend.warm_duals and graphed
    resumed = "no" if resume is None else "does not fit"
    # a state of a longer horizon (steps executed since) is read with them
    # frozen; not under a risk budget, whose levels depend on the horizon
    fits = graphed and resume is not None and (resume["offset"] == 0 or problem.model.risk_budget is None)
    prefix = int(resume["offset"]) if fits else 0
    key = _base_key(longer(problem.model, prefix), formulation, margin, regularisation) if graphed else ""
    try:
        before = direct = stepped = None
        reentered = 0
        polish_opts = backend.options(problem.solver_options, problem.tol, "polish")
        matched = fits and nlp_resume.matches(resume, backend.plugin, key, floor) \
            and nlp_resume.has_duals(resume) == backend.warm_duals
        ours = matched and backend.warm_duals            # IPOPT: resumed from the variables and multipliers
        on_graph = matched and not backend.warm_duals    # fatrop, Uno: the usual stages on the state's graph
        skip = int(resume.get("polish_skip", 0)) if ours and polish_retry else 0
        if ours and polish and resume.get("polish"):
            # the last polish's answer and multipliers: that stage alone, when it ends converged and safe
            direct = _resumed_polish(problem, backend, resume["polish"], polish_opts, floor,
                                     min(int(polish), max_iter), common, prefix)
            if direct is not None and direct.answer is not None:
                before, resumed = direct, "yes"
        if before is None and ours:
            before = _resumed(problem, backend, resume, opts, floor, max_iter - (direct.used if direct else 0),
                              common, prefix, user=first_opts)
            resumed = "does not fit" if before is None else "yes" if before.answer is not None else "fell back"
            if direct is not None and before is not None:
                before.attempts, before.used = direct.attempts + before.attempts, direct.used + before.used
        if before is None or before.answer is None:
            # the usual stage from the warm start: on the frozen graph when the
            # resumed solve ran there or the state has no multipliers (nothing
            # built), else on the problem's own
            usual = dict(formulation=formulation, floor=floor, rescue=rescue_opts, start=problem.start,
                         max_iter=max_iter - (before.used if before else 0), restarts=restarts,
                         offset=problem.iterations, scale=scale_means, **common)
            # from the re-anchored answer on its graph: the backend's resume options
            graph_opts = _with_resume_options(backend, opts, first_opts) if on_graph else opts
            first = _frozen_stage(problem, backend, prefix=prefix, opts=graph_opts, **usual) \
                if prefix and (before is not None or on_graph) else None
            if first is None:
                if prefix:                       # the problem's own graph
                    if on_graph:                 # (the prefix cannot be frozen at this start)
                        on_graph, resumed = False, "does not fit"
                    prefix, key = 0, _base_key(problem.model, formulation, margin, regularisation)
                first = _solve_stage(problem, backend, Stage(), prefix=0, opts=graph_opts if on_graph else opts,
                                     **usual)
            if on_graph:
                resumed = "graph"
            if before is not None:       # one stage in the stats: the resumed solve, then the usual one
                first.attempts, first.used = before.attempts + first.attempts, before.used + first.used
        else:
            first = before
        stages = [first]
        # a polish that did not lower a recent answer is skipped while stage 1's answer
        # is below the warm start (above it, the polish is the answer's only chance)
        skipped = bool(skip) and first is not direct and first.answer is not None \
            and first.answer[0] <= problem.cost0
        if first is direct:
            pass                         # the polish's own stage, resumed: nothing after it
        elif formulation == "logchol" and polish and not skipped and first.answer is not None \
                and first.used < max_iter \
                and not problem.out_of_time() and not problem.stop_requested:
            # the floored answer senses >= floor^2 in every direction: switch the
            # directions held at the floor off and free the rest on the exact
            # Cholesky NLP (docs/numerics.md, "IPOPT iterations"); with a step-down to
            # follow, a polish still far from feasible at its iteration PROBE ends there
            stepping = resumable and bool(step_down) and not prefix
            second = _solve_stage(problem, backend, Stage(), formulation="cholesky", floor=floor, opts=polish_opts,
                                  bounds=lambda nlp, lay: nlp.without_sensing(lay, floor), start=first.answer[1],
                                  max_iter=min(int(polish), max_iter - first.used), restarts=0,
                                  offset=problem.iterations, duals=first.duals if backend.warm_duals else None,
                                  prefix=prefix, probe=stepping, **common)
            if backend.warm_duals and still_lowering(problem, second, int(polish)) \
                    and first.used + second.used < max_iter and not problem.out_of_time() \
                    and not problem.stop_requested:
                _polish_further(problem, backend, second, first.answer[1], floor, polish_opts,
                                min(int(polish), max_iter - first.used - second.used), prefix, common)
            def solve(**kw: Any) -> Stage:
                # one attempt of a stage that continues the polish (the rounds, the step-down)
                return _solve_stage(problem, backend, Stage(), restarts=0, offset=problem.iterations, **kw, **common)

            def stepped_down() -> str | None:
                # the floored stage at a lower floor, then its polish (nlp_stepdown)
                return nlp_stepdown.step_down(problem, first, second, floor, step_down, solve,
                                              _with_resume_options(backend, opts, first_opts), polish_opts,
                                              int(polish), max_iter - first.used - second.used)
            if stepping and second.answer is None:
                stepped = stepped_down()
            lower_floor = floor * step_down if stepped == "polished" else floor
            if backend.warm_duals and reenter and not prefix:
                # switched-off sensing whose block says it lowers the cost comes back on (nlp_reentry)
                def again(bounds: Callable, duals: tuple, cap: int) -> Stage:
                    return solve(formulation="cholesky", floor=lower_floor, opts=polish_opts, bounds=bounds,
                                 start=first.answer[1], max_iter=cap, duals=duals)
                reentered = nlp_reentry.reenter(problem, second, lower_floor, reenter, again, int(polish),
                                                max_iter - first.used - second.used)
            if stepping and stepped is None and nlp_reentry.pays(problem, second):
                # switched-off sensing that would pay, and the rounds did not turn it on
                stepped = stepped_down()
            stages.append(second)
    except ValidationError as exc:
        # an option of the first stage's own that the solver refused: name that field
        named = (re.search(rf"\b{re.escape(str(k).split('.')[-1])}\b", exc.problem) for k in first_stage_options or {})
        if exc.field == "solver_options" and any(named):
            raise ValidationError("first_stage_options", exc.problem) from None
        raise
    finally:                  # also when a solver refused its options (ValidationError)
        if bar is not None:
            bar.close()
    out = outcome(problem, backend, stages, max_iter)
    out.stats["resumed"] = resumed
    out.stats["resumed_stage"] = "polish" if first is direct else "first" if resumed == "yes" else None
    if skipped:
        out.message += f"; polish skipped (a recent re-plan's did not lower its answer; {skip - 1} more skips)"
    out.stats["polish_skipped"] = skipped
    out.stats["sensing_reentered"] = reentered
    out.stats["floor_stepped_down"] = stepped
    pol = first if first is direct else stages[1] if len(stages) > 1 else None
    answered = pol is not None and pol.answer is not None and out.point is pol.answer[1]
    # stationary in S as well (nlp_stationary): auto's CCP polish could not lower it
    out.stats["sensing_stationary"] = sensing_stationary(*pol.solved, pol.z, pol.duals[1]) \
        if answered and pol.solved is not None else None
    if out.stats["sensing_stationary"] is False:
        out.message += "; sensing at a step the polish switched off would lower the cost (auto's CCP polish does)"
    if key and first.answer is not None and not backend.warm_duals:
        # a state of the graph alone (no multipliers): a re-plan after executed steps solves on it
        out.resume = nlp_resume.state(backend.plugin, key, floor, np.zeros(0), None, prefix)
    elif key and first.answer is not None and first.duals is not None:
        # the polish's state when its answer is the run's (a later re-plan resumes it alone)
        # (a polish at a stepped-down floor is not: a re-plan's resumed polish switches off at the run's floor)
        polished = (pol.z, pol.duals) if answered and stepped != "polished" else None
        if len(stages) > 1:              # a polish that did not lower stage 1's answer: skipped next time
            skip_next = 0 if out.point is not first.answer[1] else int(polish_retry)
        else:
            skip_next = skip - 1 if skipped else 0
        # after the polish alone, the first stage's state stays the earlier one's
        z, duals = (resume["z"], (resume["lam_x"], resume["lam_g"])) if first is direct else (first.z, first.duals)
        out.resume = nlp_resume.state(backend.plugin, key, floor, z, duals, prefix, polished, skip_next)
    return out


def _polish_further(problem: SmoothingProblem, backend: NLPBackend, polish: Stage, anchor: Layout, floor: float,
                    opts: dict, max_iter: int, prefix: int, common: dict) -> None:
    """One more polish from where ``polish`` stopped (:func:`_resumed_polish`
    from its variables and multipliers, on the polish's own anchor: stage 1's
    answer), merged into it: its attempts and iterations added, its answer
    (converged, exactly safe) or a lower best point taken."""
    state = {"z": polish.z, "lam_x": polish.duals[0], "lam_g": polish.duals[1]}
    more = _resumed_polish(problem, backend, state, opts, floor, max_iter, common, prefix, anchor=anchor)
    if more is not None:
        polish.absorb(more, take=more.answer is not None)


def _resumed(problem: SmoothingProblem, backend: NLPBackend, resume: dict, opts: dict, floor: float,
             max_iter: int, common: dict, prefix: int, user: dict) -> Stage | None:
    """The first stage from ``resume``'s variables and multipliers, with the
    backend's ``resume_options`` where the user's options of that stage
    (``user``: solver options with the first stage's own over them) are silent;
    one attempt of at most :data:`RESUME_LIMIT` K iterations; on ``resume``'s
    graph with its first ``prefix`` steps frozen at the problem's start
    (None when they cannot be: :func:`belief_nlp.model.nlp_prefix.frozen`)."""
    def bounds(nlp: NLPProblem, lay: Layout) -> tuple:
        # the frozen variables are fixed by their bounds: clipping sets them
        return np.clip(resume["z"], nlp.lbz, nlp.ubz), nlp.lbz, nlp.ubz

    return _frozen_stage(problem, backend, formulation="logchol", floor=floor,
                         opts=_with_resume_options(backend, opts, user),
                         start=problem.start, max_iter=min(max_iter, RESUME_LIMIT * problem.model.data.K),
                         restarts=0, offset=problem.iterations, bounds=bounds,
                         duals=(resume["lam_x"], resume["lam_g"]), prefix=prefix, **common)


def _with_resume_options(backend: NLPBackend, opts: dict, user: dict) -> dict:
    """``opts`` with the backend's ``resume_options`` where the user's
    options of the stage (``user``) are silent."""
    return {**opts, **{k: v for k, v in backend.resume_options.items() if k not in user}}


def _resumed_polish(problem: SmoothingProblem, backend: NLPBackend, state: dict, opts: dict, floor: float,
                    max_iter: int, common: dict, prefix: int, anchor: Layout | None = None) -> Stage | None:
    """The polish stage alone from an earlier polish's answer and multipliers
    (``state``), its switched-off sensing kept off; one attempt of at most
    ``max_iter`` iterations (None when the prefix cannot be frozen).
    ``anchor``: the stage's start (its proximal term's certificates and its
    first best point), the problem's start unless given."""
    def bounds(nlp: NLPProblem, lay: Layout) -> tuple:
        return nlp.switch_off(np.clip(state["z"], nlp.lbz, nlp.ubz), nlp.lbz, nlp.ubz, floor)

    start = problem.start if anchor is None else anchor
    return _frozen_stage(problem, backend, formulation="cholesky", floor=floor, opts=opts, start=start,
                         max_iter=max_iter, restarts=0, offset=problem.iterations, bounds=bounds,
                         duals=(state["lam_x"], state["lam_g"]), prefix=prefix, **common)


def _frozen_stage(problem: SmoothingProblem, backend: NLPBackend, **kw: Any) -> Stage | None:
    """:func:`_solve_stage` on a resume state's graph, or None when its prefix
    cannot be frozen at the problem's start (our ValidationError on "resume")."""
    try:
        return _solve_stage(problem, backend, Stage(), **kw)
    except ValidationError as exc:
        if exc.field != "resume":
            raise
        return None
