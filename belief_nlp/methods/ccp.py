"""CCP: the convex-concave procedure of the paper (section IV.A).

Each iteration sets the parameters of the compiled CVXPY problem of the
model's convexified program (:mod:`belief_nlp.model.doc`,
:mod:`belief_nlp.model.cvxpy_form`) at the current point and solves it; the
answer's priors are re-derived by the Kalman recursion (Lemma 2), the point
is checked exactly by the driver's shared check, and taken when it is safe
and does not raise the cost.

Guarantees: every accepted iterate is exactly safe; the cost never increases
(a step that would raise it by more than ``monotone_tol`` relative ends the
run with status "non_monotone"); a failed subproblem is retried once with
other solver settings where the solver has them, then the run ends
"solver_failed" with the best iterate.
"""

from __future__ import annotations

import logging
import time
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import ValidationError
from ..model import BeliefModel, Layout
from ..model.cache import MEMORY, DiskCache, problem_key
from ..model.cvxpy_form import CompiledProblem, compile_problem
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.policy import DEFAULT_POLICY
from ..smoother.registry import Method, Option, register
from ..smoother.result import STATUSES, IterationRecord

__all__ = ["run", "compiled_step", "ccp_subproblem", "usable_solvers", "initial_rho"]

log = logging.getLogger("belief_nlp.smoother")

CHI2_MARGIN = DEFAULT_POLICY.conic      # every collision/containment row of the step asks chi2 (1 + this)

# Clarabel: equilibration off by default -- on paper-multi (K = 5..20, both
# alphas) it ended 65 of 174 subproblems InsufficientProgress, 0 of 110
# without (docs/numerics.md). The retry turns it on, with more iterations and
# stronger regularisation: a different path through the same problem.
#
# Chordal decomposition and presolve off: the PSD cones are 2x2 to 6x6 (nothing
# to decompose), and with both off Clarabel accepts data updates, so CVXPY
# re-uses one solver object across iterations (``warm_start=True`` below)
# instead of building a new one (~10 % of an iteration at K = 20).
SOLVER_DEFAULTS = {"CLARABEL": {"equilibrate_enable": False, "chordal_decomposition_enable": False,
                                "presolve_enable": False}}
REUSE = {"CLARABEL"}
TIME_LIMIT_OPTION = {"CLARABEL": "time_limit", "SCS": "time_limit_secs"}
SOLVER_RETRY = {"CLARABEL": {"equilibrate_enable": True, "max_iter": 400, "static_regularization_constant": 1e-7},
                "SCS": {"max_iters": 50_000}}


def usable_solvers() -> list[str]:
    """Installed CVXPY solvers that take PSD and exponential cones (the CCP step needs both)."""
    import cvxpy as cp
    from cvxpy.reductions.solvers.defines import SOLVER_MAP_CONIC

    out = []
    for name in cp.installed_solvers():
        s = SOLVER_MAP_CONIC.get(name)
        if s is None:
            continue
        kinds = {c.__name__ for c in s.SUPPORTED_CONSTRAINTS}
        if {"SOC", "ExpCone"} <= kinds and kinds & {"PSD", "SvecPSD"}:
            out.append(name)
    return out


def _check_solver(name: str) -> str | None:
    ok = usable_solvers()
    if name.upper() not in ok:
        return f"{name!r} cannot solve the CCP step (it needs PSD and exponential cones); usable installed solvers: {ok}"
    return None


def _check_solver_options(solver: str, options: dict) -> None:
    if solver == "CLARABEL":
        import clarabel

        st = clarabel.DefaultSettings()
        for k in options:
            if not hasattr(st, k):
                raise ValidationError("solver_options", f"{k!r} is not a Clarabel setting")


def compiled_step(model: BeliefModel, solver: str = "CLARABEL", cache_dir: str | Path | bool | None = None,
                  chi2_margin: float = CHI2_MARGIN) -> tuple[CompiledProblem, str, DiskCache | None]:
    """The compiled CVXPY problem of ``model``'s CCP step: from memory, from the
    disk cache (``cache_dir``: True = the user's cache folder, or a folder),
    else compiled. Returns (problem, where it came from, the disk cache)."""
    key = problem_key(model.data, chi2_margin, solver)
    hit = MEMORY.get(key)
    disk = None
    if cache_dir:
        disk = DiskCache(None if cache_dir is True else cache_dir)
    if hit is not None:
        return hit, "memory", disk
    if disk is not None:
        hit = disk.load(key)
        if isinstance(hit, CompiledProblem):
            MEMORY.put(key, hit)
            return hit, "disk", disk
    form = model.convex_form if chi2_margin == CHI2_MARGIN else None
    if form is None:
        from ..model.doc import convex_form

        form = convex_form(model.data, chi2_margin)
    step = compile_problem(form)
    MEMORY.put(key, step)
    return step, "compiled", disk


def initial_rho(model: BeliefModel, z: Layout) -> np.ndarray:
    """Split weights rho (K, J) for the first step.

    The majorant's error 1/2 ||sqrt(rho) dv - dx / sqrt(rho)||^2 is smallest for
    rho = ||dx|| / ||dv||; before any step, take the mean step length for
    ||dx|| and ||v~|| for ||dv|| (a certificate can change by its own size)."""
    steps = np.linalg.norm(np.diff(z.x, axis=0), axis=1)
    step_scale = max(float(np.mean(steps)), 1e-3)
    vnorm = np.linalg.norm(np.einsum("jfd,kjf->kjd", model.data.A, z.lam), axis=-1)
    return step_scale / np.maximum(vnorm, 1e-6)


def _adapt_rho(model: BeliefModel, z: Layout, z_new: Layout, rho_s: np.ndarray, rho_e: np.ndarray):
    """Weights for the next step from the step just taken (any rho > 0 is valid)."""
    A = model.data.A
    dv = np.linalg.norm(np.einsum("jfd,kjf->kjd", A, z_new.lam - z.lam), axis=-1)
    out = []
    for rho, dx in ((rho_s, np.linalg.norm(z_new.x[:-1] - z.x[:-1], axis=-1)[:, None]),
                    (rho_e, np.linalg.norm(z_new.x[1:] - z.x[1:], axis=-1)[:, None])):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(dv > 1e-9, dx / dv, rho)
        out.append(np.clip(np.where(r > 0, r, rho), rho / 10, rho * 10))
    return out


def _solve(step: CompiledProblem, solver: str, options: dict, retry: bool,
           time_left: float | None = None) -> tuple[str, np.ndarray | None, float, int]:
    import cvxpy as cp

    opts = dict(SOLVER_DEFAULTS.get(solver, {}))
    if retry:
        opts.update(SOLVER_RETRY[solver])
    if time_left is not None and solver in TIME_LIMIT_OPTION:     # the run's budget bounds one solve too
        opts[TIME_LIMIT_OPTION[solver]] = max(float(time_left), 1e-3)
    opts.update(options)
    try:
        with warnings.catch_warnings():       # "may be inaccurate": the status says so, and the exact check decides
            warnings.simplefilter("ignore", UserWarning)
            step.problem.solve(solver=solver, warm_start=solver in REUSE, **opts)
    except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
        return f"error: {str(exc).splitlines()[0][:120]}", None, 0.0, 0
    st = step.problem.solver_stats
    status = str(step.problem.status)
    ok = status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) and step.z.value is not None
    return _checked(status, np.asarray(step.z.value, float) if ok else None, float(st.solve_time or 0.0),
                    int(st.num_iters or 0), step)


def _checked(status: str, zv: np.ndarray | None, t: float, n: int, step: CompiledProblem):
    """A solver answer that is not a finite vector of the right length, or whose
    entries are absurd (|z| > 1e12 in the model's O(1) units), is a failed
    subproblem, whatever status the solver reported."""
    if zv is not None:
        zv = np.asarray(zv, dtype=float)
        if zv.shape != (step.layout.blocks.n,) or not np.all(np.isfinite(zv)) or np.max(np.abs(zv)) > 1e12:
            return f"{status} (unusable answer)", None, t, n
    return status, zv, t, n


def run(problem: SmoothingProblem, *, monotone_tol: float = 1e-7, rho: float | None = None,
        cache_dir: str | Path | bool | None = None, constraints: Callable | None = None,
        hook: Callable | None = None, _fail_at: int | None = None, _start: Layout | None = None) -> Outcome:
    """CCP from the problem's start (see the module doc and :data:`METHOD`).

    ``_start`` (for composite methods): continue from this exactly safe point
    instead; iterations are numbered after the problem's history and count
    against the same ``max_iter``."""
    model, D = problem.model, problem.model.data
    solver = (problem.solver or "CLARABEL").upper()
    _check_solver_options(solver, problem.solver_options)
    if problem.out_of_time():                      # the warm start used the budget up
        return Outcome("time_limit", f"{STATUSES['time_limit']} (before the first step)", None, solver)
    t_build = time.perf_counter()
    step, origin, disk = compiled_step(model, solver, cache_dir)
    if constraints is not None:
        step = step.with_constraints(constraints(step))
    build_time = time.perf_counter() - t_build
    z, cost = (problem.start, problem.cost0) if _start is None else (_start, model.cost(_start)[0])
    first = len(problem.history)                 # 1 for a plain run; after a previous stage's records
    rho_e = np.full((D.K, D.J), float(rho)) if rho else initial_rho(model, z)
    rho_s = rho_e.copy()
    status, message = "max_iter", STATUSES["max_iter"]
    bar = problem.progress_bar("CCP")
    # the same raw keys as the NLP methods: return_status (the last subproblem's),
    # iter_count (CCP steps), cpu_time (this process, the run's steps)
    stats = {"compile": origin, "build_time": build_time, "solver_iterations": 0, "return_status": "",
             "iter_count": 0, "solve_time": 0.0, "cpu_time": 0.0}
    cpu0 = time.process_time()
    for it in range(first, problem.max_iter + 1):
        if problem.out_of_time():
            status, message = "time_limit", STATUSES["time_limit"]
            break
        t_it = time.perf_counter()
        step.set_point(z, rho_s, rho_e)
        if hook is not None:
            extra = hook(step, it)
            if extra:
                step = step.with_constraints(extra)
                step.set_point(z, rho_s, rho_e)
        z_new, kgap, sstat, stime, sit = None, float("nan"), "", 0.0, 0
        for retry in (False, True):
            if retry and (solver not in SOLVER_RETRY or problem.out_of_time()):
                break
            if _fail_at is not None and it >= _fail_at:       # injected fault (tests)
                sstat, zv, st, n = "injected failure", None, 0.0, 0
            else:
                sstat, zv, st, n = _solve(step, solver, problem.solver_options, retry, problem.time_left())
            stime, sit = stime + st, sit + n
            if zv is not None:
                try:
                    z_raw = step.layout.extract(zv, z)
                    kgap = model.kalman_relative_gap(z_raw)
                    z_new = model.tighten(z_raw)
                except (np.linalg.LinAlgError, ValueError, FloatingPointError):  # degenerate: a failed step
                    sstat, z_new = f"{sstat} (degenerate answer)", None
            if z_new is not None:
                break
            log.warning("CCP iteration %d: subproblem %s%s", it, sstat, "" if retry else "; retrying")
        stats["solver_iterations"] += sit
        stats["iter_count"] += 1
        stats["solve_time"] += stime
        stats["return_status"] = sstat
        if origin == "compiled" and disk is not None and z_new is not None and it == 1 and not step.user:
            disk.save(problem_key(D, CHI2_MARGIN, solver), step)
        if z_new is None:
            problem.record(IterationRecord(it, np.nan, np.nan, np.nan, sstat, stime, 0.0,
                                           time.perf_counter() - t_it, sit, accepted=False))
            if problem.out_of_time():            # the solve was cut by the run's time limit
                status, message = "time_limit", f"{STATUSES['time_limit']} (during iteration {it})"
            else:
                status, message = ("solver_failed",
                                   f"{STATUSES['solver_failed']}: solver status {sstat} at iteration {it}")
            break
        chk = problem.check(z_new)
        if not chk.safe:
            chk = problem.repair(chk) or chk
            sstat = f"{sstat}+repaired" if chk.safe else sstat
        c_new, ctrl, info = model.cost(chk.point)
        rec = IterationRecord(it, c_new, ctrl, info, sstat, stime, 0.0, 0.0, sit, accepted=chk.safe,
                              min_margin=chk.margin, kalman_gap=kgap)
        if not chk.safe:
            rec.wall_time = time.perf_counter() - t_it
            problem.record(rec)
            status = "infeasible_iterate"
            message = (f"{STATUSES[status]}: iteration {it} has clearance margin {chk.margin:.3g} "
                       f"and target margin {chk.target:.3g}")
            break
        if not c_new <= cost * (1 + monotone_tol) + 1e-12:     # NaN fails too
            rec.accepted = False
            rec.wall_time = time.perf_counter() - t_it
            problem.record(rec)
            status = "non_monotone"
            message = f"{STATUSES['non_monotone']}: cost {cost:.8g} -> {c_new:.8g} at iteration {it}"
            log.warning(message)
            break
        rho_s, rho_e = _adapt_rho(model, z, chk.point, rho_s, rho_e) if not rho else (rho_s, rho_e)
        rel = (cost - c_new) / max(abs(cost), 1e-300)
        z, cost = chk.point, c_new
        rec.wall_time = time.perf_counter() - t_it
        stop = problem.record(rec, z)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(cost=f"{cost:.5g}")
        log.info("CCP iteration %d: cost %.8g (control %.4g, info %.4g nats), solver %s %.3fs",
                 it, cost, ctrl, info, sstat, stime)
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
    return Outcome(status, message, None, solver, stats)


def _positive(v: Any) -> str | None:
    return None if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 else "must be a number > 0"


def _nonneg(v: Any) -> str | None:
    return None if isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0 else "must be a number >= 0"


def _callable_or_none(v: Any) -> str | None:
    return None if v is None or callable(v) else "must be None or a callable"


METHOD = register(Method(
    name="ccp", run=run, max_iter=50, default_solver="CLARABEL", check_solver=_check_solver,
    description="convex-concave procedure (paper IV.A): monotone, every iterate exactly safe",
    iteration="one convex (SDP) step",
    options={
        "monotone_tol": Option(1e-7, "relative cost increase that ends the run (non_monotone)", _nonneg),
        "rho": Option(None, "fixed split weight of h2 (None: adapted per pair)",
                      lambda v: None if v is None else _positive(v)),
        "cache_dir": Option(None, "disk cache of compiled problems: None (memory only), True (user cache), or a folder",
                            lambda v: None if v is None or isinstance(v, (bool, str, Path)) else
                            "must be None, True or a folder"),
        "constraints": Option(None, "fn(step) -> extra CVXPY constraints for every step (e.g. on step.means())",
                              _callable_or_none),
        "hook": Option(None, "fn(step, iteration) before each solve, parameters set; may return constraints to "
                             "add for the rest of the run", _callable_or_none),
        "_fail_at": Option(None, "testing: make every subproblem from this iteration on fail"),
        "_start": Option(None, "composite methods: continue from this exactly safe point"),
    },
))


def ccp_subproblem(scenario, path, K: int | None = None, alpha: float | None = None):
    """The convex subproblem of the first CCP step, as a ``cvxpy.Problem``.

    Built from ``path``'s warm start with its parameters set, ready to
    ``.solve()`` (the smoother uses CLARABEL with ``equilibrate_enable=False``),
    to print, or to hand to another solver.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario, or a built-in name / scenario file.
    path : BeliefPath, result or WarmStart
        A feasible path (or a plan or smoothing result holding one), or a
        warm start used as it is.
    K : int, optional
        Horizon of the warm start; None as in :func:`belief_nlp.warm_start`.
    alpha : float, optional
        Information weight; None uses the scenario's.

    Returns
    -------
    cvxpy.Problem
        The step's problem; its variable ``z`` is the model's decision vector
        (scaled units; docs/architecture.md).

    Raises
    ------
    InfeasibleStartError
        When no feasible warm start can be built from ``path``.
    ValidationError
        For bad arguments, naming the argument.
    """
    from ..smoother.driver import _path, _scenario
    from ..smoother.warmstart import WarmStart, warm_start

    sc = _scenario(scenario)
    p = _path(path)
    warm = p if isinstance(p, WarmStart) else warm_start(sc, p, K=K)
    model = BeliefModel(sc, warm.K, alpha)
    start = model.tighten(model.from_path(warm.path, warm.lam))
    step, _, _ = compiled_step(model)
    rho = initial_rho(model, start)
    step.set_point(start, rho, rho)
    return step.problem
