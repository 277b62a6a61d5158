"""``smooth``: the one entry point of every smoothing method, and the shared
driver that makes them report alike.

The driver owns what is common: argument checks, the warm start, the model,
the time budget (it starts before the warm start), the exact safety check
(:meth:`SmoothingProblem.check`), independent verification, the choice of
the answer and the :class:`SmoothResult`. A method only iterates.

One meaning for every method (docs/architecture.md, "The contract"):
* ``max_iter`` -- the method's iterations in total (CCP steps, NLP solver
  iterations), restarts included; None = the method's own default;
* ``tol`` -- relative optimality tolerance: CCP stops when a step lowers the
  cost by less than tol (relative); NLP solvers get it as their own
  (scaled, relative) KKT tolerance;
* ``status`` -- one of :data:`STATUSES`; ``success`` only for "converged";
* ``accepted`` (history) -- the iterate passed the method's feasibility test.
The answer is the method's point when it is exactly safe, passes
:func:`belief_nlp.verify` and costs no more than the warm start; otherwise
the lowest-cost accepted iterate that does, at worst the warm start, with an
honest status.
"""

from __future__ import annotations

import logging
import math
import time
from contextlib import contextmanager
from typing import Any, Callable

import numpy as np

from ..allocation import RiskAllocation, RiskBudget, tail
from .._limits import MAX_ALPHA
from ..errors import InfeasibleStartError, ValidationError
from ..inputs import as_path, as_scenario
from ..model import BeliefModel, Layout
from ..path import BeliefPath
from ..scenario import Scenario
from .context import Outcome, SmoothingProblem
from .registry import DEFAULT_METHOD, Method, real, resolve_method
from .result import STATUSES, SmoothResult
from .budget_start import budget_warm_start
from .warmstart import WarmStart, warm_start

__all__ = ["smooth"]

log = logging.getLogger("belief_nlp.smoother")

MAX_K = 2000


@contextmanager
def _logging_to_stderr():
    """INFO lines of the library on stderr for the duration of one call."""
    lib = logging.getLogger("belief_nlp")
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    old = lib.level
    lib.addHandler(handler)
    lib.setLevel(logging.INFO)
    try:
        yield
    finally:
        lib.removeHandler(handler)
        lib.setLevel(old)


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return real(v) is not None


def _check_args(max_iter, tol, alpha, time_limit, K, solver_options, callback) -> None:
    if max_iter is not None and (not _is_int(max_iter) or max_iter < 1):
        raise ValidationError("max_iter", f"must be None or a positive integer, got {max_iter!r}")
    if not _is_num(tol) or not (0 < tol < 1):
        raise ValidationError("tol", f"must be a number in (0, 1), got {tol!r}")
    # the scenario's and the planner's bound too (_limits): at alpha = 4e10 the control term
    # fell below the solvers' tolerances and a CCP step ground in SCS for 62 s (session 21)
    if alpha is not None and (not _is_num(alpha) or not math.isfinite(alpha) or not 0 <= alpha <= MAX_ALPHA):
        raise ValidationError("alpha", f"must be None or a finite number in [0, {MAX_ALPHA:g}], got {alpha!r}")
    if time_limit is not None and (not _is_num(time_limit) or not math.isfinite(time_limit) or time_limit <= 0):
        raise ValidationError("time_limit", f"must be None or a finite number > 0, got {time_limit!r}")
    if K is not None and (not _is_int(K) or not 1 <= K <= MAX_K):
        raise ValidationError("K", f"must be None or an integer in [1, {MAX_K}], got {K!r}")
    if solver_options is not None and not isinstance(solver_options, dict):
        raise ValidationError("solver_options", f"must be a dict, got {type(solver_options).__name__}")
    if callback is not None and not callable(callback):
        raise ValidationError("callback", f"must be callable, got {type(callback).__name__}")


def smooth(scenario: Scenario | str, path: Any, method: str | Callable | Method = DEFAULT_METHOD, K: int | None = None,
           max_iter: int | None = None, tol: float = 1e-4, solver: str | None = None, alpha: float | None = None, *,
           time_limit: float | None = None, solver_options: dict | None = None, keep_iterates: bool = False,
           progress: bool = False, sensing: str = "minimal", callback: Callable | None = None,
           verbose: bool = False, k_fallback: bool = True, risk: float | RiskBudget | None = None,
           allocation: str = "optimal", risk_kind: str = "steps", **options: Any) -> SmoothResult:
    """Smooth a feasible belief path toward a local optimum of the paper's problem.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario, or a built-in name / scenario file.
    path : BeliefPath, PlanResult, SmoothResult, WarmStart, str or path
        Any feasible path (planner output, hand-made), a result (its path is
        taken), a :class:`WarmStart` used as it is, or a file holding a plan,
        a path or a smoothing result (JSON or NPZ, as ``belief-nlp smooth
        --path`` reads).
    method : str, Method or callable, optional
        A name from :func:`available_methods` -- ``"auto"`` (the default,
        :data:`DEFAULT_METHOD`): IPOPT on the exact NLP, then CCP from the
        best exactly safe point when IPOPT's answer is not taken, and a
        short CCP polish after a converged one (``result.method`` says which
        ran: ``"auto:ipopt+ccp"``, ``"auto:ipopt"`` or ``"auto:ccp"``); ``"ccp"``: the convex-concave procedure, paper
        section IV, every iterate feasible; ``"ipopt"``: the exact NLP by
        IPOPT alone; ``"sqp"``: a filter-SQP baseline -- a registered
        :class:`Method`, or a callable ``fn(problem, **options)`` returning
        an :class:`Outcome`.
    K : int, optional
        Horizon (number of time steps); None gives one step per path edge
        (see :func:`warm_start`).
    max_iter : int, optional
        Iteration limit; None uses the method's own default.
    tol : float, optional
        Relative optimality tolerance (default 1e-4; module doc).
    solver : str, optional
        The method's solver (CCP: any installed CVXPY solver with PSD and
        exponential cones, default CLARABEL; auto and ipopt: IPOPT, auto's
        CCP stage takes ``ccp_solver=``); None uses the method's default.
    alpha : float, optional
        Information weight in [0, 1e6] (the scenario's bound); None uses the scenario's. At 0 sensing costs
        nothing and the NLP has no minimiser: the NLP methods refuse it,
        ``auto`` answers with CCP.
    time_limit : float, optional
        Wall-time budget in seconds, warm start and model build included.
    solver_options : dict, optional
        Options passed to the solver.
    keep_iterates : bool, optional
        Also return the path of every accepted iterate (``result.iterates``).
    progress : bool, optional
        Show a progress bar.
    sensing : {"minimal", "path"}, optional
        How the warm start sets covariances (see :func:`warm_start`).
    callback : callable, optional
        ``callback(record)`` after every iteration with its
        :class:`IterationRecord`; returning True (or raising StopIteration,
        as with scipy.optimize) stops the run with status "stopped".
    verbose : bool, optional
        Log every iteration (and the method's decisions) to stderr.
    k_fallback : bool, optional
        When no feasible warm start exists at the requested K (per-step
        noise on every sub-step can make a sub-transition next to an
        obstacle unsafe), fall back to one step per path edge and say so in
        ``stats["warm_start"]`` and the message (default); False raises instead.
    risk : float or RiskBudget, optional
        An end-to-end collision-probability budget Delta in (0, 0.5) for the
        whole path, in place of the scenario's fixed collision level (the
        target keeps the scenario's confidence): the certified probability of
        being inside some hazard at the K + 1 step times stays <= Delta
        (:mod:`belief_nlp.allocation`). None: ``scenario.risk`` when the
        scenario sets one, else the paper's fixed level.
    allocation : {"optimal", "uniform"}, optional
        With ``risk``: per-pair levels chosen by the smoother (decision
        variables of the model; default) or Delta split equally over the K J
        transition-hazard pairs.
    risk_kind : {"steps", "continuous"}, optional
        What the budget bounds: "steps" (default), the probability of being
        inside a hazard at the step times; "continuous", of touching one at
        any instant (through a per-pair surrogate, :mod:`belief_nlp.allocation`;
        the reported bound is the exact continuous-time formula's). Both
        bounds are always reported in ``verification``.
    **options
        The method's own options (``get_method(name).options`` documents
        them), as keywords or, as with scipy, in one ``options={...}``
        dict. CCP-only options such as ``constraints`` or ``hook`` need
        ``method="ccp"``.

    Returns
    -------
    SmoothResult
        Its path is always exactly safe and independently verified, never
        costlier than the warm start; ``success`` when the method converged.
        With ``risk``, ``result.risk`` holds the allocation and the certified
        bound.

    Raises
    ------
    ValidationError
        For bad arguments or method options, and for a solver the method
        cannot use; the error names the argument.
    InfeasibleStartError
        When no feasible warm start can be built from ``path``.
    """
    if verbose:
        with _logging_to_stderr():
            return smooth(scenario, path, method, K, max_iter, tol, solver, alpha, time_limit=time_limit,
                          solver_options=solver_options, keep_iterates=keep_iterates, progress=progress,
                          sensing=sensing, callback=callback, verbose=False, k_fallback=k_fallback, risk=risk,
                          allocation=allocation, risk_kind=risk_kind, **options)
    t0 = time.perf_counter()
    scenario = as_scenario(scenario)
    path = as_path(path)
    m = resolve_method(method)
    _check_args(max_iter, tol, alpha, time_limit, K, solver_options, callback)
    opts = m.validate(_merge_options(options))
    budget = _budget(scenario, risk, allocation, risk_kind)
    if solver is not None and not isinstance(solver, str):
        raise ValidationError("solver", f"must be a solver name, got {type(solver).__name__}")
    solver_name = solver if solver is not None else m.default_solver
    if m.check_solver is not None and solver_name is not None:
        problem = m.check_solver(solver_name)
        if problem:
            raise ValidationError("solver", problem)
    if isinstance(path, WarmStart):
        if K is not None and K != path.K:
            raise ValidationError("K", f"the given warm start has K = {path.K}, not {K}")
        warm = path
        ws_info = {"K": warm.K, "requested_K": K, "fallback": False}
    else:
        warm, ws_info = _warm_start(scenario, path, K, sensing, k_fallback, budget)
    model = BeliefModel(scenario, warm.K, alpha, risk=budget)
    problem = SmoothingProblem(scenario, warm, model, max_iter=m.max_iter if max_iter is None else int(max_iter),
                               tol=tol, time_limit=time_limit, t0=t0, solver=solver_name,
                               solver_options=solver_options or {}, progress=progress,
                               keep_iterates=keep_iterates, callback=callback, method=m.name)
    t_setup = time.perf_counter() - t0
    outcome = m.run(problem, **opts)
    outcome.stats.setdefault("warm_start", ws_info)
    if ws_info["fallback"]:
        outcome.message += (f" [warm start: K = {ws_info['requested_K']} was infeasible, one step per path edge "
                            f"used (K = {warm.K})]")
    if not isinstance(outcome, Outcome) or outcome.status not in STATUSES:
        raise ValidationError("method", f"{m.name!r} returned {outcome!r}; a method returns an Outcome "
                                        f"with a status from {sorted(STATUSES)}")
    return _finish(problem, outcome, m, t_setup)


def _merge_options(options: dict) -> dict:
    """The method's options from keywords and, scipy's habit, an ``options={...}`` dict."""
    options = dict(options)
    extra = options.pop("options", None)
    if extra is None:
        return options
    if not isinstance(extra, dict):
        raise ValidationError("options", f"must be a dict of the method's options, got {type(extra).__name__}")
    both = sorted(set(extra) & set(options))
    if both:
        raise ValidationError("options", f"{both} given both as keywords and in options={{...}}")
    return {**extra, **options}


def _budget(scenario: Scenario, risk: Any, allocation: Any, kind: Any) -> RiskBudget | None:
    """The run's risk budget: ``risk`` (a number or a RiskBudget), else the scenario's."""
    if risk is not None and scenario.start_confidence is not None:
        raise ValidationError("start.confidence", "a start held to its own level cannot be smoothed under a risk "
                                                  "budget, which prices the start belief itself")
    if isinstance(risk, RiskBudget):
        return risk
    if risk is None:
        risk = getattr(scenario, "risk", None)
    if risk is None:
        if not (isinstance(allocation, str) and allocation.lower() == "optimal") or kind != "steps":
            RiskBudget(0.05, allocation, kind)               # a bad value still gets its own error
            raise ValidationError("allocation", "applies only with a risk budget (give risk=...)")
        return None
    return RiskBudget(risk, allocation, kind)


def _warm_start(scenario: Scenario, path: BeliefPath, K: int | None, sensing: str,
                fallback: bool, budget: RiskBudget | None = None) -> tuple[WarmStart, dict]:
    """The warm start at K, or -- when K is infeasible and fallback allowed -- at
    one step per path edge; with what happened. Under a risk budget the
    collisions are cleared at a level that fits it (:mod:`.budget_start`)."""

    def build(k: int | None) -> WarmStart:
        if budget is None:
            # not verified here: the start is proven by the exact check and the
            # path returned is verified (_finish), the warm start included
            return warm_start(scenario, path, K=k, sensing=sensing, verify_start=False)
        return budget_warm_start(scenario, path, k, sensing, budget)

    try:
        warm = build(K)
        return warm, {"K": warm.K, "requested_K": K, "fallback": False}
    except InfeasibleStartError as exc:
        if not fallback or K is None or K == path.K:
            raise
        log.warning("no feasible warm start at K = %d (%s); using one step per path edge (K = %d)", K, exc, path.K)
        warm = build(None)
        return warm, {"K": warm.K, "requested_K": K, "fallback": True, "reason": str(exc)}


def _finish(problem: SmoothingProblem, outcome: Outcome, m: Method, t_setup: float) -> SmoothResult:
    """Choose the answer (module doc) and build the result."""
    from ..verify import verify

    model, sc = problem.model, problem.scenario
    status, message = outcome.status, outcome.message
    candidates: list[tuple[float, int, Layout, str]] = []
    if outcome.point is not None:
        chk = problem.check(outcome.point)
        if chk.safe:
            candidates.append((model.cost(chk.point)[0], -1, chk.point, "the method's answer"))
        elif status == "converged":
            status = "infeasible_iterate"
            message = f"{message}; its answer failed the exact safety check ({STATUSES[status]})"
    for it, z in problem.points.items():
        candidates.append((model.cost(z)[0], it, z, f"iterate {it}"))
    candidates.sort(key=lambda c: (c[0], c[1] != -1))
    intended = candidates[0][3] if candidates else "the warm start"
    solver = outcome.solver or problem.solver or ""
    method_name = outcome.label or m.name
    meta = {"method": method_name, "solver": solver, "alpha": model.data.alpha}
    answer, origin, report, path = problem.start, "the warm start", None, None
    for cost, it, z, where in candidates:
        if not np.isfinite(cost):
            continue
        if cost > problem.cost0 * (1 + 1e-12) + 1e-15:
            break
        # the path verified is the path returned (verify reads no meta): built once
        cand = model.to_path(z, meta=meta)
        rep = verify(sc, cand, certificates=z.lam / model.data.sigma, **_risk_args(model, z))
        if rep.safe:
            answer, origin, report, path = z, where, rep, cand
            break
        log.warning("%s failed independent verification; trying the next candidate", where)
    best = candidates[0][0] if candidates else np.inf
    within_tol = problem.cost0 < best <= problem.cost0 * (1 + problem.tol)
    if status == "converged" and origin == "the warm start" and within_tol:
        # a start that is already optimal (a re-plan from the planned belief): the method
        # converged no lower, within tol (relative) of it, so the start is optimal to tol
        message = (f"{message}; the warm start is returned: the answer was {best / problem.cost0 - 1:.1e} above it, "
                   f"within tol = {problem.tol:g}")
    elif status == "converged" and origin != intended:
        status = "above_start" if best > problem.cost0 else "infeasible_iterate"
        message = f"{message}; {origin} is returned ({STATUSES[status]})"
    if path is None:
        path = model.to_path(answer, meta=meta)
    lam_si = answer.lam / model.data.sigma
    if report is None:                    # the warm start: verified here (the candidates were above)
        report = verify(sc, path, certificates=lam_si, **_risk_args(model, answer))
        if not report.safe:               # what warm_start() raises when it verifies (smooth defers it to here)
            raise InfeasibleStartError(f"warm start failed verification: {report.summary()}")
    c, ctrl, info = model.cost(answer)
    iterates = None
    if problem.keep_iterates:
        iterates = [model.to_path(problem.start)] + [model.to_path(z) for _, z in sorted(problem.points.items())]
    hist = problem.history
    nit = problem.iterations
    if status == "max_iter":
        # say the limit and what one iteration is ("after N iterations" alone
        # reads as a failure, and N may be below the limit: module doc of nlp_engine)
        limit = int(outcome.stats.get("iteration_limit", problem.max_iter))
        message = f"{message}; {nit} of at most {limit} iterations" + (
            f" (each {m.iteration})" if m.iteration != "iteration" else "")
    return SmoothResult(
        path=path, cost=c, control=ctrl, information=info, success=status == "converged", status=status,
        message=message, nit=nit, history=hist, method=method_name, solver=solver, alpha=model.data.alpha,
        timings={"setup": t_setup, "solver": float(sum(h.solve_time for h in hist)),
                 "total": time.perf_counter() - problem.t0},
        verification=report.to_dict(), initial_cost=problem.cost0, iterates=iterates, stats=dict(outcome.stats),
        certificates=lam_si, risk=_allocation(problem, answer, report), resume=outcome.resume)


def _risk_args(model: BeliefModel, z: Layout) -> dict:
    """verify()'s collision levels and budget for a point of ``model``."""
    D = model.data
    budget = model.risk_budget
    if budget is None:
        return {}
    return {"levels": z.tau if D.budget is not None and z.tau is not None else D.chi2, "budget": budget.budget,
            "risk_kind": budget.kind}


def _allocation(problem: SmoothingProblem, z: Layout, report) -> RiskAllocation | None:
    """The returned path's :class:`RiskAllocation` (None without a budget)."""
    model = problem.model
    budget = model.risk_budget
    if budget is None:
        return None
    D = model.data
    levels = np.array(z.tau if D.budget is not None and z.tau is not None else np.full((D.K, D.J), D.chi2), float)
    bound = report.risk.continuous if budget.kind == "continuous" else report.risk_bound
    return RiskAllocation(budget.budget, budget.factor * tail(levels), levels, float(bound), budget.allocation,
                          budget.kind, tuple(h.name for h in problem.scenario.hazards))
