"""auto: the NLP first, the convex-concave procedure as its fallback.

IPOPT solves the exact NLP from the warm start. Its answer is taken when
IPOPT converged and the point passes the shared certified check (the driver
then also verifies it and holds it to the warm start's cost). Otherwise --
failure, stall, time, or an unsafe end point -- CCP continues from the best
exactly safe point found so far (IPOPT's recorded candidates, at worst the
warm start), and its monotone descent gives the answer. After a converged
IPOPT answer, CCP runs at most ``ccp_polish`` steps (10) from it, kept only
if they lower the cost: CCP sometimes finds a lower local optimum. Measured
(benchmarks/bench_ccp.py --methods auto,auto+polish -> results/ccp_polish.json,
60 cases): the median cost falls (ratio 0.999999 at K = 20, 0.99991 at K = 40;
8 of 20 K = 40 cases lower by more than 0.1 %, at most 0.70 %) for +2.5 % and
+5 % median wall, so it is on by default (``ccp_polish=0`` turns it off),
except after an IPOPT answer from a converged exact polish that is
stationary for the sensing it switched off (:mod:`.nlp_stationary`): a CCP
step from such a point returns it. On the issue-21 protocol that skips the
polish in 31 of 40 runs at K = 20 and 30 of 40 at K = 40, which it had
lowered by at most 3.6e-5 relative (docs/numerics.md, "Skipping the CCP
polish at a stationary answer").
Under a risk budget the default is no polish: the budgeted CCP step has no
active-set form and costs ~10x more (notebook 06: 2.1 s -> 7.5 s for a
0.03 % lower cost). Nor after a re-plan whose IPOPT stage resumed from an
earlier answer and ended on its converged exact polish (``bn.replan`` in a
loop): there the CCP polish took 0.1-0.2 s of a 0.15-0.45 s re-plan and
lowered the cost by at most 8e-5 relative (receding loops: 1.4e-5 in
session 14, -4e-6 .. 8e-5 on this session's 40; same-horizon re-plans
at K = 20: 6.2e-5 median; docs/numerics.md, "The polish resumed alone").
An explicit ``ccp_polish`` is always honoured.

One budget: ``max_iter`` counts IPOPT iterations and CCP steps together
(``ccp_reserve`` of it is kept for CCP); the time limit is the run's. The
result's ``method`` says which stages ran ("auto:ipopt+ccp": IPOPT's answer
polished; "auto:ipopt": no polish; "auto:ccp": CCP from IPOPT's best safe
point) and the history holds both stages' records. Each outcome keeps
IPOPT's state (``SmoothResult.resume``) when IPOPT converged, "auto:ccp"
too: a re-plan after executed steps then resumes IPOPT on the same graph,
and both CCP stages use that graph's conic step, frozen alike.

After an "auto:ccp" answer whose IPOPT stage converged above the warm
start (or unsafe), the next ``ipopt_retry`` (4) re-plans run CCP alone from
their warm start, the last answer moved on, and IPOPT is tried again after
them. Resumed from its own earlier answer, IPOPT lands near that local
optimum again, above CCP's: at K = 80 on paper-multi it spent 1.4-2.9 s of
a 2.4-4.6 s re-plan for nothing, and CCP alone gave the same cost in
1.0-1.5 s (docs/numerics.md, "The work around a loop step, and auto in a
loop at K = 80 (session 16)").
``stats["ipopt_skipped"]`` marks such runs.
"""

from __future__ import annotations

from typing import Any

from ..errors import ValidationError
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.registry import Method, Option, count, register
from . import ccp, ipopt
from .ccp_steps import prefetch_conic_step

__all__ = ["run", "FIRST_STAGE", "POLISH"]

#: CCP polish steps after a converged IPOPT answer (``ccp_polish=None``, without a risk budget)
POLISH = 10

#: re-plans that run CCP alone after an answer CCP gave because IPOPT's was not taken
IPOPT_RETRY = 4

#: the NLP method of the first stage: ``ipopt`` (or ``fatrop``: one line to
#: switch). IPOPT stays: on the same NLP and warm starts fatrop stops at
#: points 0.1-1 % costlier at IPOPT's tolerance and needs more iterations or
#: fails at tighter ones (benchmarks/bench_nlp_speed.py, docs/numerics.md "fatrop").
FIRST_STAGE = ipopt


def _stage(problem: SmoothingProblem, budget: int, fn, solver: str, solver_options: dict, **kw: Any) -> Outcome:
    """Run one stage with ``budget`` iterations in total so far (the shared
    count), its own solver and solver options."""
    saved = problem.max_iter, problem.solver, problem.solver_options
    problem.max_iter = min(budget, saved[0])
    problem.solver, problem.solver_options = solver, dict(solver_options)
    try:
        return fn(problem, **kw)
    finally:
        problem.max_iter, problem.solver, problem.solver_options = saved


def _resumed_polished(first: Outcome) -> bool:
    """Whether IPOPT resumed from an earlier answer and its exact polish
    converged to the answer: a re-plan in a loop, where the default skips
    the CCP polish (module doc)."""
    return first.stats.get("resumed") == "yes" and bool((first.resume or {}).get("polish"))


def _totals(stats: dict, answer: str) -> dict:
    """The raw keys every method's stats carry, summed over the stages;
    return_status is the answering stage's."""
    stages = [stats[k] for k in ("ipopt", "ccp") if k in stats]
    stats["iter_count"] = int(sum(s.get("iter_count", 0) for s in stages))
    stats["cpu_time"] = float(sum(s.get("cpu_time", 0.0) for s in stages))
    stats["restoration"] = stats.get("ipopt", {}).get("restoration")
    stats["return_status"] = stats.get(answer, {}).get("return_status", "")
    return stats


def _ccp_answer(problem: SmoothingProblem, ccp_opts: tuple, start, prefix: int, stats: dict, why: str,
                state: dict | None) -> Outcome:
    """The "auto:ccp" outcome: CCP from ``start`` with the rest of the budget
    (after executed steps on the state's longer conic step, frozen alike),
    ``stats`` holding the stages before it; ``state`` is the next re-plan's."""
    second = _stage(problem, problem.max_iter, ccp.run, *ccp_opts, _start=start, _prefix=prefix)
    stats.update(ccp=second.stats, stages=[*stats.get("stages", []), "ccp"])
    return Outcome(second.status, f"{why}: {second.message}", None, ccp_opts[0], _totals(stats, "ccp"), "auto:ccp",
                   state)


def run(problem: SmoothingProblem, *, ccp_reserve: int = 50, ccp_polish: int | None = None, ccp_solver: str = "CLARABEL",
        ccp_solver_options: dict | None = None, ipopt_options: dict | None = None,
        ipopt_retry: int = IPOPT_RETRY, resume: dict | None = None) -> Outcome:
    """IPOPT, then CCP when IPOPT's answer is not taken (module doc). The
    run's ``solver_options`` go to IPOPT; CCP's come from ``ccp_solver_options``;
    ``ipopt_options`` are the first stage's method options (``floor``,
    ``polish``, ...: those of ``method="ipopt"``); ``resume`` goes to the
    IPOPT stage unless ``ipopt_options`` gives its own."""
    ccp_opts = (ccp_solver, ccp_solver_options or {})
    skip = resume.get("stage_skip", 0) if resume is not None and (ipopt_options or {}).get("resume") is None else 0
    if skip:                     # CCP alone from the warm start, IPOPT's state kept with one skip less (module doc)
        return _ccp_answer(problem, ccp_opts, problem.start, int(resume["offset"]), {"ipopt_skipped": True},
                           f"IPOPT skipped (the last answer was CCP's; {skip - 1} more re-plans skip it); CCP",
                           {**resume, "stage_skip": skip - 1})
    if problem.model.data.alpha == 0:    # sensing costs nothing: the NLP has no minimiser (nlp_engine.run_nlp)
        return _ccp_answer(problem, ccp_opts, problem.start, int((resume or {}).get("offset", 0)),
                           {"ipopt_skipped": True}, "IPOPT skipped (alpha = 0: the NLP has no minimiser); CCP", None)
    polish_default = ccp_polish is None
    if ccp_polish is None:       # under a risk budget a CCP step is ~10x dearer (no active-set step): no polish
        ccp_polish = POLISH if problem.model.data.budget is None else 0
    reserve = min(ccp_reserve, problem.max_iter // 2)
    if ccp_polish and ccp_opts[0].upper() == "CLARABEL" and problem.model.data.budget is None:
        # the polish's active-set step, when no cache has it, built beside IPOPT's solve (first
        # call on a model: 0.23 s above the next instead of 0.35 s at
        # K = 20: docs/performance.md, "Smoothing: the first call of a process")
        problem.while_solving.append(lambda: prefetch_conic_step(problem.model))
    # IPOPT's polish always runs here: its converged answer is what lets a re-plan skip the CCP polish
    # (10 steps of ~0.7 s at K = 80; with the polish skipped after a miss, seed 2 of
    # receding_auto_k80.json took 6.6-8.2 s a re-plan instead of 0.3-1.3 s)
    first_options = {"polish_retry": 0, **({"resume": resume} if resume is not None else {}),
                     **(ipopt_options or {})}
    first = _stage(problem, problem.max_iter - reserve, FIRST_STAGE.run, FIRST_STAGE.METHOD.default_solver,
                   problem.solver_options, **first_options)
    stats: dict[str, Any] = {"ipopt": first.stats, "stages": ["ipopt"]}
    # after executed steps (a re-plan) CCP solves the conic step of the state's longer horizon, frozen alike
    prefix = int((first_options.get("resume") or {}).get("offset", 0))
    if polish_default and (_resumed_polished(first) or first.stats.get("sensing_stationary")):
        ccp_polish = 0           # a CCP step from a point stationary in S returns it (module doc)
    if first.status == "converged" and first.point is not None:
        chk = problem.check(first.point)
        if chk.safe and problem.model.cost(chk.point)[0] <= problem.cost0:
            if not ccp_polish or problem.out_of_time():
                return Outcome("converged", f"IPOPT: {first.message}", chk.point, "IPOPT", _totals(stats, "ipopt"),
                               "auto:ipopt", first.resume)
            problem.points[problem.iterations] = chk.point
            # a polish step that Clarabel's entries cannot answer ends the polish (IPOPT's answer
            # stands): alpha = 1e-6 sent one such step on to SCS at high accuracy for 110 s
            second = _stage(problem, problem.iterations + ccp_polish, ccp.run, *ccp_opts, _start=chk.point,
                            _prefix=prefix, _head_only=True)
            stats.update(ccp=second.stats, stages=["ipopt", "ccp polish"])
            # the driver picks the lowest-cost verified candidate: IPOPT's point or a polished one
            return Outcome("converged", f"IPOPT: {first.message}; CCP polish: {second.status}", None, "IPOPT+CCP",
                           _totals(stats, "ipopt"), "auto:ipopt+ccp", first.resume)
    if problem.out_of_time() or problem.stop_requested:
        return Outcome(first.status, f"IPOPT: {first.message}", first.point, "IPOPT", _totals(stats, "ipopt"),
                       "auto:ipopt")
    # CCP from the best exactly safe point so far
    best = min(problem.points.items(), key=lambda kv: problem.model.cost(kv[1])[0], default=(None, None))[1]
    start = best if best is not None and problem.model.cost(best)[0] <= problem.cost0 else problem.start
    # IPOPT's state, when it converged (above the warm start, or refused): a later
    # re-plan resumes it on this graph instead of building the next horizon's, after
    # ipopt_retry re-plans that run CCP alone (IPOPT's answer would not be taken again)
    state = None if first.resume is None else {**first.resume, "stage_skip": int(ipopt_retry)}
    return _ccp_answer(problem, ccp_opts, start, prefix, stats, f"IPOPT: {first.status}; CCP from the best safe point",
                       state)


def _check_first_stage_options(v: Any) -> str | None:
    """``ipopt_options``: the first stage's method options, checked as that method checks them."""
    if v is None:
        return None
    if not isinstance(v, dict):
        return "must be a dict of the first stage's method options"
    try:
        FIRST_STAGE.METHOD.validate(v)
    except ValidationError as exc:
        return f"{exc.field!r} {exc.problem}"
    return None


METHOD = register(Method(
    name="auto", run=run, max_iter=3000, default_solver=FIRST_STAGE.METHOD.default_solver,
    check_solver=lambda s: None if s.upper() == FIRST_STAGE.METHOD.default_solver.upper()
    else f"method 'auto' runs {FIRST_STAGE.METHOD.default_solver} first (ccp_solver= picks the CCP stage's solver), "
         f"got {s!r}",
    description="IPOPT on the exact NLP; CCP from the best safe point when IPOPT's answer is not taken",
    iteration="one IPOPT iteration or one CCP step",
    options={"ccp_reserve": Option(50, "iterations of the budget kept for the CCP fallback", count),
             "ccp_polish": Option(None, "CCP steps tried after a converged IPOPT answer, kept only if lower "
                                   f"(None: {POLISH} without a risk budget, 0 under one, after a resumed "
                                   "IPOPT stage whose exact polish answered, or at an answer stationary "
                                   "for its switched-off sensing)",
                                   lambda v: None if v is None else count(v)),
             "ccp_solver": Option("CLARABEL", "conic solver of the CCP stage", ccp._check_solver),
             "ccp_solver_options": Option(None, "solver options of the CCP stage (solver_options go to IPOPT)",
                                          lambda v: None if v is None or isinstance(v, dict) else "must be a dict"),
             "ipopt_retry": Option(IPOPT_RETRY, "re-plans (bn.replan) after an answer CCP gave because IPOPT's "
                                                "was not taken that run CCP alone from the warm start, before "
                                                "IPOPT is tried again (0: IPOPT every time)", count),
             "ipopt_options": Option(None, "method options of the IPOPT stage, e.g. {'floor': 5e-3} (those of "
                                           "method 'ipopt'; solver_options are IPOPT's own)",
                                     _check_first_stage_options),
             "resume": Option(None, "an earlier answer's first-stage state (SmoothResult.resume) for the IPOPT "
                                    "stage: its option 'resume' (bn.replan passes it)",
                              FIRST_STAGE.METHOD.options["resume"].check)},
))
