"""CCP: the convex-concave procedure of the paper (section IV.A).

Each iteration sets the parameters of the compiled CVXPY problem of the
model's convexified program (:mod:`belief_nlp.model.doc`,
:mod:`belief_nlp.model.cvxpy_form`) at the current point and solves it; the
answer's priors are re-derived by the Kalman recursion (Lemma 2), the point
is checked exactly by the driver's shared check, and taken when it is safe
and does not raise the cost.

Acceleration (``accelerate=True``, the default): from the second step on,
the step is first linearised at the extrapolated point y = z + beta (z - z_prev)
(Nesterov's momentum sequence, as in accelerated DC algorithms). Every
majorant of the step is a global upper bound whatever the linearisation
point, so the step's feasible set is an inner approximation of the true one
at y too and its answer is exactly safe even when y is not; it is taken when
it lowers the cost, else the plain step at z follows and the momentum
restarts (docs/numerics.md, "Accelerated CCP").

Guarantees: every accepted iterate is exactly safe; the cost never
increases. A step is solved along a cascade of conic solvers and settings
(:func:`solver_cascade`): a failed or inaccurate solve, and an answer that
the exact check refuses or that raises the cost by more than
``monotone_tol`` relative (the exact step is feasible and monotone, so that
is solver inaccuracy), go on to the next entry. Only when every entry fails
does the run end "solver_failed" (no answer), "infeasible_iterate" or
"non_monotone" (answers, all refused), with the best iterate;
``stats["steps"]`` says which solver answered each step.

Cost of a run: the step is compiled once per (scenario, K) -- alpha is its
parameter -- and kept in memory. With the active-set step (the default, with
Clarabel) the CVXPY problem is compiled only when a step needs it (an answer
the active-set step could not give): ``stats["compile"]`` is then
"not needed", else where the problem came from ("compiled", "memory", "disk").
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..model import BeliefModel, Layout
from ..model.data import psd_part
from ..geometry.transitions import transition_minimiser
from ..model.cache import problem_key
from ..model.cvxpy_form import CompiledProblem, usable_solvers
from .ccp_steps import CHI2_MARGIN, compiled_step, conic_step_of, frozen_step
from .ccp_cascade import (SOLVER_DEFAULTS, LazyCascade, _check_solver, _check_solver_options, _checked, _solve,
                          _StepAnswers, solver_cascade)
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.registry import Method, Option, nonneg, real, register
from ..smoother.result import STATUSES, IterationRecord

__all__ = ["run", "compiled_step", "solver_cascade", "usable_solvers", "initial_rho", "SOLVER_DEFAULTS",
           "active_pairs", "conic_step_of"]

log = logging.getLogger("belief_nlp.smoother")

RHO_BAND = 100.0      # adapted split weights stay within this factor of the first step's (_adapt_rho)
ACTIVE_FACTOR = 3.0   # the active-set step keeps the pairs whose exact squared distance is below this x chi2
ACTIVE_ROUNDS = 3      # solves of the active-set step, each adding the pairs its answer came near
HOLD_ACTIVE = True     # a step starts from the pairs the previous step's active set ended with
PROXIMAL = 1e-4       # weight of the cascade's proximal step (scaled units; docs/numerics.md, "CCP solver cascade")

def active_pairs(model: BeliefModel, point: Layout, hazards) -> np.ndarray:
    """Pairs (K * J, flattened k * J + j) whose transition comes within
    ACTIVE_FACTOR chi2 (squared Mahalanobis distance, exact minimum over the
    segment) of its hazard at ``point``: the pairs the active-set step keeps."""
    level = ACTIVE_FACTOR * model.data.chi2
    tm = transition_minimiser(*model.segments(point), hazards, threshold=level)   # dist2 on the right side of it
    return np.asarray(tm.dist2, float).ravel() < level


def initial_rho(model: BeliefModel, z: Layout) -> np.ndarray:
    """Split weights rho (K, J) for the first step.

    The majorant's error 1/2 ||sqrt(rho) dv - dx / sqrt(rho)||^2 is smallest for
    rho = ||dx|| / ||dv||; before any step, take the mean step length for
    ||dx|| and ||v~|| for ||dv|| (a certificate can change by its own size)."""
    steps = np.linalg.norm(np.diff(z.x, axis=0), axis=1)
    step_scale = max(float(np.mean(steps)), 1e-3)
    vnorm = np.linalg.norm(np.einsum("jfd,kjf->kjd", model.data.A, z.lam), axis=-1)
    return step_scale / np.maximum(vnorm, 1e-6)


def _extrapolate(model: BeliefModel, z: Layout, z_prev: Layout, beta: float) -> Layout:
    """The point y = z + beta (z - z_prev) to linearise at (accelerated CCP): S
    projected on the PSD cone, lam on lam >= 0, levels into their bounds and Q
    rolled out from S by the Kalman recursion, so Y~ is positive definite."""
    D = model.data
    y = z.copy()
    y.x[1:] = z.x[1:] + beta * (z.x[1:] - z_prev.x[1:])
    y.S[1:] = psd_part(z.S[1:] + beta * (z.S[1:] - z_prev.S[1:]))
    y.lam = np.maximum(z.lam + beta * (z.lam - z_prev.lam), 0.0)
    if z.tau is not None:
        lo, hi = D.level_bounds
        y.tau = np.clip(z.tau + beta * (z.tau - z_prev.tau), lo, hi)
    return model.tighten(y)


def _adapt_rho(model: BeliefModel, z: Layout, z_new: Layout, rho_s: np.ndarray, rho_e: np.ndarray,
               rho0: np.ndarray):
    """Weights for the next step from the step just taken (any rho > 0 is valid),
    within RHO_BAND of the first step's ``rho0``: a pair whose mean or
    certificate barely moved gives a meaningless ratio, and the weights then
    spread over 13 decades (1.6e-7 to 5.6e6 on paper-multi), putting entries
    that far apart into one cone of the step -- Clarabel's defaults then fail
    (docs/numerics.md, "Conditioning of the CCP step")."""
    A = model.data.A
    dv = np.linalg.norm(np.einsum("jfd,kjf->kjd", A, z_new.lam - z.lam), axis=-1)
    out = []
    for rho, dx in ((rho_s, np.linalg.norm(z_new.x[:-1] - z.x[:-1], axis=-1)[:, None]),
                    (rho_e, np.linalg.norm(z_new.x[1:] - z.x[1:], axis=-1)[:, None])):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(dv > 1e-9, dx / dv, rho)
        out.append(np.clip(np.clip(np.where(r > 0, r, rho), rho / 10, rho * 10), rho0 / RHO_BAND, rho0 * RHO_BAND))
    return out


def run(problem: SmoothingProblem, *, monotone_tol: float = 1e-7, rho: float | None = None,
        cache_dir: str | Path | bool | None = None, constraints: Callable | None = None,
        hook: Callable | None = None, accelerate: bool = True, active_set: bool = True,
        resume: dict | None = None, _fail_at: int | None = None, _start: Layout | None = None,
        _prefix: int = 0, _head_only: bool = False) -> Outcome:
    """CCP from the problem's start (see the module doc and :data:`METHOD`).

    ``_start`` (for composite methods): continue from this exactly safe point
    instead; iterations are numbered after the problem's history and count
    against the same ``max_iter``. ``_prefix`` > 0 (a re-plan after that
    many executed steps): the active-set step is the one of the horizon
    ``_prefix`` steps longer, when it is in memory, with those steps frozen
    (:mod:`belief_nlp.model.conic_prefix`), and no CVXPY step follows it;
    ``resume`` (an earlier answer's state, ``bn.replan(..., advance=k)``)
    gives that offset. The outcome's state says the offset of the step used.
    ``_head_only`` (auto's polish): a step is answered by the chosen
    solver's first entries only (on its own data: the active-set and full
    steps), never by the cascade's slower rest (CVXPY's compile, SCS at high
    accuracy): a step they cannot answer ends the run, whose start stands."""
    model, D = problem.model, problem.model.data
    _prefix = _prefix or (int(resume["offset"]) if resume is not None else 0)
    solver = (problem.solver or "CLARABEL").upper()
    _check_solver_options(solver, problem.solver_options)
    if problem.out_of_time():                      # the warm start used the budget up
        return Outcome("time_limit", f"{STATUSES['time_limit']} (before the first step)", None, solver)
    # the active-set step (Clarabel's own data, far pairs left out): without
    # user constraints and a risk budget, with Clarabel
    use_active = active_set and constraints is None and hook is None and D.budget is None and solver == "CLARABEL"
    stats: dict[str, Any] = {"frozen": 0}     # steps of a longer horizon frozen (_prefix)

    def build_step():
        t_build = time.perf_counter()
        step_, stats["compile"], stats["disk"] = compiled_step(model, solver, cache_dir)
        if constraints is not None:
            step_ = step_.with_constraints(constraints(step_))
        stats["build_time"] = time.perf_counter() - t_build
        return step_

    conic, frozen = None, None
    if use_active:
        # the CVXPY step is compiled only when a step needs it (an answer the
        # active-set step cannot give): most runs never do (0.3-0.7 s saved)
        t0 = time.perf_counter()
        frozen = frozen_step(model, _prefix) if _prefix else None
        conic = frozen or conic_step_of(model, cache_dir)
        stats["active_set_build_time"] = time.perf_counter() - t0
        if frozen is not None:
            stats["frozen"] = _prefix
        step = _LazyStep(conic.layout, build_step)
    else:
        step = build_step()
    z, cost = (problem.start, problem.cost0) if _start is None else (_start, model.cost(_start)[0])
    first = problem.iterations + 1               # 1 for a plain run; after a previous stage's records
    rho_e = np.full((D.K, D.J), float(rho)) if rho else initial_rho(model, z)
    rho_s = rho_e.copy()
    rho0 = rho_e.copy()
    status, message = "max_iter", STATUSES["max_iter"]
    bar = problem.progress_bar("CCP")
    # the same raw keys as the NLP methods: return_status (the last subproblem's),
    # iter_count (CCP steps), cpu_time (this process, the run's steps)
    # steps: per iteration, the solver (and settings) whose answer was taken and every attempt
    stats.setdefault("compile", "not needed")         # (the CVXPY step: compiled, memory, disk or not needed)
    stats.setdefault("build_time", 0.0)
    stats.update({"solver_iterations": 0, "return_status": "", "iter_count": 0, "solve_time": 0.0, "cpu_time": 0.0,
                  "steps": [], "active_pairs": []})
    budget = problem.model.data.budget is not None
    if conic is None:
        cascade = solver_cascade(solver, problem.solver_options, budget=budget)
        if _head_only:
            cascade = cascade[:1]
    else:
        # the active-set step, then the full step on the same Clarabel data (every
        # pair kept: the problem of the CVXPY step's first entry, without CVXPY's
        # import and compile, 0.7-1.4 s); the rest of the cascade (and CVXPY)
        # only when neither answer is taken
        lib = {**SOLVER_DEFAULTS["CLARABEL"], **problem.solver_options}
        cascade = LazyCascade([("CLARABEL", "active set", lib), ("CLARABEL", "full step", lib)],
                              # the CVXPY step is of the shorter horizon when frozen
                              (lambda: []) if frozen is not None or _head_only
                              else lambda: solver_cascade(solver, problem.solver_options, budget=budget))
    prox: dict = {}            # the proximal step: compiled on first use; not with a hook's own constraints
    held: dict = {"keep": None}

    def special(base: Layout, rho_s_: np.ndarray, rho_e_: np.ndarray) -> dict[str, Callable]:
        def proximal(opts: dict, time_left: float | None):
            if prox.get("hooked"):
                return None
            if "step" not in prox:
                t0 = time.perf_counter()
                ps = compiled_step(model, "CLARABEL", cache_dir, proximal=PROXIMAL)[0]
                prox["step"] = ps.with_constraints(constraints(ps)) if constraints is not None else ps
                stats["proximal_build_time"] = time.perf_counter() - t0
            prox["step"].set_point(base, rho_s_, rho_e_)
            return _solve(prox["step"], "CLARABEL", opts, time_left)

        def active(opts: dict, time_left: float | None):
            # constraint generation: pairs the answer comes near join the step,
            # which is solved again (at most ACTIVE_ROUNDS times; the exact check decides)
            keep = active_pairs(model, base, problem.hazards_scaled)
            if HOLD_ACTIVE and held["keep"] is not None:   # the pairs the last step ended with start this one
                keep = keep | held["keep"]
            t_all, n_all = 0.0, 0
            for _ in range(ACTIVE_ROUNDS):
                status, zv, t, n = conic.solve(base, rho_s_, rho_e_, keep, opts, problem.time_left())
                t_all, n_all = t_all + t, n_all + n
                if zv is None or not np.all(np.isfinite(zv)):
                    break
                try:
                    near = active_pairs(model, model.tighten(step.layout.extract(zv, base)), problem.hazards_scaled)
                except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                    break
                if not np.any(near & ~keep):
                    break
                keep = keep | near
            stats["active_pairs"].append(int(keep.sum()))
            held["keep"] = keep
            return _checked(status, zv, t_all, n_all, step)

        def full(opts: dict, time_left: float | None):
            keep = np.ones(model.data.K * model.data.J, dtype=bool)
            return _checked(*conic.solve(base, rho_s_, rho_e_, keep, opts, time_left), step)

        return {"proximal": proximal, "active set": active, "full step": full}

    z_prev, t_mom = None, 1.0
    cpu0 = time.process_time()
    for it in range(first, problem.max_iter + 1):
        if problem.out_of_time():
            status, message = "time_limit", STATUSES["time_limit"]
            break
        t_it = time.perf_counter()
        taken, refused, attempts, stime, sit = None, None, [], 0.0, 0
        # accelerated CCP: first linearise at the extrapolated point y (the step's
        # feasible set is an inner approximation at any point, so its answer is
        # exactly safe like any other); taken only when it lowers the cost,
        # otherwise the plain step at z follows and the momentum restarts
        bases = [(z, cascade)]
        t_next = 0.5 * (1 + np.sqrt(1 + 4 * t_mom**2))
        if accelerate and z_prev is not None:
            beta = (t_mom - 1) / t_next
            if beta > 0:
                bases.insert(0, (_extrapolate(model, z, z_prev, beta), cascade[:1]))    # one entry only
        for base, entries in bases:
            prepare = None
            if conic is None:
                step.set_point(base, rho_s, rho_e)
            else:                         # only when a CVXPY entry runs (the active-set step has its own data)
                prepare = (lambda b=base, rs=rho_s, re_=rho_e: step.set_point(b, rs, re_))
            if hook is not None:
                extra = hook(step, it)
                if extra:
                    step = step.with_constraints(extra)
                    step.set_point(base, rho_s, rho_e)
                    prox["hooked"] = True
            answers = _StepAnswers(step, entries, problem, fail=_fail_at is not None and it >= _fail_at,
                                   special=special(base, rho_s, rho_e), prepare=prepare)
            plain = base is z
            while (ans := answers.next()) is not None:
                name, sstat, zv = ans
                try:
                    z_raw = step.layout.extract(zv, base)
                    kgap = model.kalman_relative_gap(z_raw)
                    z_new = model.tighten(z_raw)
                except (np.linalg.LinAlgError, ValueError, FloatingPointError):  # degenerate: try the next answer
                    answers.attempts[-1]["status"] += " (degenerate answer)"
                    continue
                chk = problem.check(z_new)
                if not chk.safe and plain:
                    chk = problem.repair(chk) or chk
                    sstat = f"{sstat}+repaired" if chk.safe else sstat
                c_new, ctrl, info = model.cost(chk.point)
                if not plain:
                    if chk.safe and c_new < cost:
                        taken = (f"{name} extrapolated", sstat, chk, c_new, ctrl, info, kgap)
                        break
                    answers.attempts[-1]["status"] += " (extrapolated: not taken)"
                    continue
                if not chk.safe:
                    refused = ("infeasible_iterate", name, sstat, chk, c_new, ctrl, info, kgap,
                               f"clearance margin {chk.margin:.3g} and target margin {chk.target:.3g}")
                elif not c_new <= cost * (1 + monotone_tol) + 1e-12:     # NaN fails too
                    refused = ("non_monotone", name, sstat, chk, c_new, ctrl, info, kgap,
                               f"cost {cost:.8g} -> {c_new:.8g}")
                else:
                    taken = (name, sstat, chk, c_new, ctrl, info, kgap)
                    break
                if "active set" in name:       # a pair left out came near: the full step decides
                    log.info("CCP iteration %d: the active-set answer is refused (%s); solving the full step",
                             it, refused[-1])
                else:
                    log.warning("CCP iteration %d: the answer of %s is refused (%s); solving more accurately",
                                it, name, refused[-1])
            attempts += answers.attempts
            stime, sit = stime + answers.solve_time, sit + answers.iterations
            if taken is not None:
                t_mom = t_next if not plain or len(bases) == 1 else 1.0
                break
        answers.attempts = attempts
        answers.solve_time, answers.iterations = stime, sit
        stime, sit = answers.solve_time, answers.iterations
        stats["solver_iterations"] += sit
        stats["iter_count"] += 1
        stats["solve_time"] += stime
        stats["steps"].append({"iteration": it, "solver": taken[0] if taken else None, "attempts": answers.attempts})
        last = answers.attempts[-1]["status"] if answers.attempts else ""
        stats["return_status"] = taken[1] if taken else last
        disk = stats.get("disk")
        if stats["compile"] == "compiled" and disk is not None and taken is not None and not step.user:
            disk.save(problem_key(D, CHI2_MARGIN, solver), step)
            stats["disk"] = None                # saved once
        if taken is None and refused is None:
            problem.record(IterationRecord(it, np.nan, np.nan, np.nan, last, stime, 0.0,
                                           time.perf_counter() - t_it, sit, accepted=False))
            if problem.out_of_time():            # the solve was cut by the run's time limit
                status, message = "time_limit", f"{STATUSES['time_limit']} (during iteration {it})"
            else:
                tried = ", ".join(f"{a['solver']} ({a['settings']}): {a['status']}" for a in answers.attempts)
                status, message = ("solver_failed",
                                   f"{STATUSES['solver_failed']}: solver status {last} at iteration {it} "
                                   f"(tried {tried})")
            break
        if taken is None:                       # every answer refused: the last refusal ends the run
            status, name, sstat, chk, c_new, ctrl, info, kgap, why = refused
            problem.record(IterationRecord(it, c_new, ctrl, info, sstat, stime, 0.0, time.perf_counter() - t_it,
                                           sit, accepted=False, min_margin=chk.margin, kalman_gap=kgap))
            message = f"{STATUSES[status]}: {why} at iteration {it} (last answer from {name})"
            log.warning(message)
            break
        name, sstat, chk, c_new, ctrl, info, kgap = taken
        rec = IterationRecord(it, c_new, ctrl, info, sstat, stime, 0.0, 0.0, sit, accepted=True,
                              min_margin=chk.margin, kalman_gap=kgap)
        rho_s, rho_e = _adapt_rho(model, z, chk.point, rho_s, rho_e, rho0) if not rho else (rho_s, rho_e)
        rel = (cost - c_new) / max(abs(cost), 1e-300)
        z_prev, z, cost = z, chk.point, c_new
        rec.wall_time = time.perf_counter() - t_it
        stop = problem.record(rec, z)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(cost=f"{cost:.5g}")
        log.info("CCP iteration %d: cost %.8g (control %.4g, info %.4g nats), %s %s %.3fs",
                 it, cost, ctrl, info, name, sstat, stime)
        if rel < problem.tol:
            status, message = "converged", f"{STATUSES['converged']} ({rel:.2e} < {problem.tol:g}) after {it} iterations"
            break
        if stop:
            status = "stopped" if problem.stop_requested else "time_limit"
            message = STATUSES[status]
            break
    if bar is not None:
        bar.close()
    stats["cpu_time"] = time.process_time() - cpu0
    stats.pop("disk", None)
    if frozen is not None and status in _FAILED and not problem.out_of_time() and not problem.stop_requested:
        # the frozen step has no CVXPY cascade behind it (that is the shorter
        # horizon's): go on from the last accepted point on the horizon's own step
        log.info("CCP: the frozen step ended %s; going on with the horizon's own step", status)
        out = run(problem, monotone_tol=monotone_tol, rho=rho, cache_dir=cache_dir, accelerate=accelerate,
                  active_set=active_set, _fail_at=_fail_at, _start=z)
        out.stats["frozen_failed"] = {"status": status, "iter_count": stats["iter_count"],
                                      "cpu_time": stats["cpu_time"]}
        return out
    # a later re-plan after executed steps solves the step used here with them frozen
    return Outcome(status, message, None, solver, stats,
                   resume=None if conic is None else {"offset": stats["frozen"]})


#: a run's end without an answer of its last step (solver_failed: none came; the others: all refused)
_FAILED = ("solver_failed", "infeasible_iterate", "non_monotone")


class _LazyStep:
    """The CVXPY step, compiled by ``build`` when first used; its layout (the
    active-set step's: both come from the model's one convex form) at once."""

    def __init__(self, layout, build: Callable[[], CompiledProblem]):
        self.layout = layout
        self._build = build
        self._step: CompiledProblem | None = None

    def __getattr__(self, name: str):      # only for what the instance does not hold itself
        if name.startswith("__"):
            raise AttributeError(name)
        if self._step is None:
            self._step = self._build()
        return getattr(self._step, name)


def _positive(v: Any) -> str | None:
    return None if (real(v) or 0) > 0 else "must be a number > 0"


#: a fixed split weight scales the two halves of the step's norm apart, sqrt(rho) dv
#: against dx / sqrt(rho): on the fuzz tests' case (paper-multi, K = 5) 1e-20 .. 1e15
#: solved in 0.02-0.08 s, 1e16 in 0.37 s, and from 1e18 on Clarabel had no answer and SCS
#: crawled (8 s to a time limit of 8 s; 28 s for two iterations without one)
RHO_RANGE = (1e-12, 1e12)


def _check_rho(v: Any) -> str | None:
    if v is None:
        return None
    lo, hi = RHO_RANGE
    return _positive(v) or (None if lo <= float(v) <= hi else
                            f"must be within [{lo:g}, {hi:g}] (scaled units): beyond, the step's cone is too "
                            f"badly scaled for its solvers; got {float(v):g}")


def _callable_or_none(v: Any) -> str | None:
    return None if v is None or callable(v) else "must be None or a callable"


def _check_resume(v: Any) -> str | None:
    """None, or a state with the steps executed since its graph (``offset``)."""
    ok = v is None or (isinstance(v, dict) and isinstance(v.get("offset"), int) and not isinstance(v["offset"], bool)
                       and v["offset"] >= 0)
    return None if ok else "must be None or a SmoothResult's resume state (SmoothResult.resume)"


METHOD = register(Method(
    name="ccp", run=run, max_iter=50, default_solver="CLARABEL", check_solver=_check_solver,
    description="convex-concave procedure (paper IV.A): monotone, every iterate exactly safe",
    iteration="one convex (SDP) step",
    options={
        "monotone_tol": Option(1e-7, "relative cost increase that ends the run (non_monotone)", nonneg),
        "rho": Option(None, f"fixed split weight of h2 (None: adapted per pair), within "
                            f"[{RHO_RANGE[0]:g}, {RHO_RANGE[1]:g}]", _check_rho),
        "cache_dir": Option(None, "disk cache of compiled problems: None (the process's: set_disk_cache, "
                                  "off by default), False (memory only), True (user cache), or a folder",
                            lambda v: None if v is None or isinstance(v, (bool, str, Path)) else
                            "must be None, True, False or a folder"),
        "constraints": Option(None, "fn(step) -> extra CVXPY constraints for every step (e.g. on step.means())",
                              _callable_or_none),
        "hook": Option(None, "fn(step, iteration) before each solve, parameters set; may return constraints to "
                             "add for the rest of the run", _callable_or_none),
        "accelerate": Option(True, "linearise first at an extrapolated point (Nesterov momentum); taken only "
                                   "when it lowers the cost", lambda v: None if isinstance(v, bool) else "must be True or False"),
        "active_set": Option(True, "solve each step first with only the pairs within "
                                   f"{ACTIVE_FACTOR:g} chi2 (the full step when the exact check refuses)",
                             lambda v: None if isinstance(v, bool) else "must be True or False"),
        "resume": Option(None, "an earlier answer's state (SmoothResult.resume; bn.replan passes it): after "
                               "executed steps, the step built for its longer horizon, when still in memory, "
                               "with those steps frozen", _check_resume),
        "_fail_at": Option(None, "testing: make every subproblem from this iteration on fail"),
        "_start": Option(None, "composite methods: continue from this exactly safe point"),
    },
))
