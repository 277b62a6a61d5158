"""Run one case: plan, warm start, smooth with every method variant, verify, record.

:func:`run_case` is what executors ship to workers (a top-level function of
plain data: it pickles for a process pool and for Dask). It never raises for
a failing case: the rows say why (``status`` "plan_failed",
"warm_start_failed", "error" or "timeout", the text in ``error``).

Row columns (one row per case and method variant; docs/studies.md):

identity  study, case_key, arm, scenario, scenario_kind, scenario_ref, seed, alpha, K (asked; None = one
          step per edge), K_used, planner (JSON), planner_<option> (each planner option), planner_name
          ("igrrt" or "ompl:<Class>"), planner_backend (IG-RRT*'s attempts: "numba" or "numpy"), method (label),
          method_name, method_options (JSON)
outcome   status, success, message, error, safe, min_margin, worst, warm_start_fallback, fallback_reason
costs     planner_cost (the planner's own objective), warm_start_cost, cost, control, information,
          iterations
timings   plan_time, warm_start_time, build_time, solve_time, smooth_time, wall_time (plan + warm start +
          smoothing: the path's total), trace (JSON [[t, best cost], ...] from t = 0 at planning),
          plan_trace (JSON [[t, best planner cost], ...]: the planner's anytime curve, PlanResult.cost_trace)
solver    solver, stats (JSON of SmoothResult.stats)
safety    mc_runs, mc_failures, mc_rate, mc_ci_low, mc_ci_high, nominal_rate, mc_collisions, mc_exits,
          mc_misses (Monte-Carlo metric: runs that hit an obstacle / left the domain / missed the target)
library   belief_nlp_version, solver_version, versions (JSON), case (JSON: reproduces the case), finished_at
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from contextlib import contextmanager
from functools import lru_cache
from typing import Any, Iterator

import numpy as np

from .cases import Case, MethodVariant, canonical_json

__all__ = ["run_case", "TIMING_COLUMNS", "FAILED", "versions"]

#: Columns that legitimately differ between two runs of the same case (clock
#: readings and the compile cache's state); everything else is reproducible.
TIMING_COLUMNS = ("plan_time", "warm_start_time", "build_time", "solve_time", "smooth_time", "wall_time",
                  "trace", "plan_trace", "stats", "finished_at")
#: Statuses of rows without a smoothed path.
FAILED = ("plan_failed", "warm_start_failed", "error", "timeout")
#: "none" as a method: the warm start itself, scored on the smoother's objective (the raw plan's arm).
NO_SMOOTHING = "none"


class CaseTimeout(Exception):
    """The case ran past its ``case_timeout``."""


@lru_cache(maxsize=1)
def versions() -> dict[str, str]:
    """Versions of the library and of the numerical packages it runs on."""
    import platform
    from importlib import metadata

    out = {"python": platform.python_version()}
    for dist in ("belief-nlp", "numpy", "scipy", "cvxpy", "clarabel", "casadi"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = ""
    return out


_SOLVER_DIST = {"CLARABEL": "clarabel", "IPOPT": "casadi", "SCS": "scs", "MOSEK": "mosek"}


@contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise CaseTimeout in this thread after ``seconds`` -- where a signal can
    reach it (the main thread of a pool worker). Elsewhere (a Dask worker's
    thread) the case relies on the planner's and smoother's own time limits."""
    usable = seconds is not None and seconds > 0 and threading.current_thread() is threading.main_thread() \
        and hasattr(signal, "setitimer")
    if not usable:
        yield
        return

    fired = []
    message = f"case ran longer than its case_timeout of {seconds:g} s"

    def _raise(signum, frame):
        fired.append(True)
        raise CaseTimeout(message)

    old = signal.signal(signal.SIGALRM, _raise)
    # raised again every 0.1 s, and once more after the case: an exception raised
    # inside a destructor or weakref callback is printed and dropped by Python
    # (seen: a 0.01 s timeout swallowed in WeakSet._remove, the case ran on)
    signal.setitimer(signal.ITIMER_REAL, float(seconds), 0.1)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
    if fired:
        raise CaseTimeout(message)


def _base_row(case: Case, variant: MethodVariant) -> dict:
    v = versions()
    row: dict[str, Any] = {
        "study": case.study, "case_key": case.key, "arm": case.arm, "scenario": case.scenario.label,
        "scenario_kind": case.scenario.kind, "scenario_ref": case.scenario.ref, "seed": case.seed,
        "alpha": case.alpha, "K": case.K, "K_used": None, "planner": canonical_json(case.planner),
        "planner_backend": ""}
    for k, val in sorted(case.planner.items()):
        row[f"planner_{k}"] = val if isinstance(val, (int, float, str, bool)) else json.dumps(val)
    row.update({
        "planner_name": str(case.planner.get("planner", "igrrt")),
        "method": variant.label, "method_name": variant.method, "method_options": canonical_json(variant.options),
        "status": "error", "success": False, "message": "", "error": None, "safe": False,
        "min_margin": math.nan, "worst": "", "warm_start_fallback": False, "fallback_reason": "",
        "planner_cost": math.nan, "warm_start_cost": math.nan, "cost": math.nan, "control": math.nan,
        "information": math.nan, "iterations": 0, "plan_time": math.nan, "warm_start_time": math.nan,
        "build_time": math.nan, "solve_time": math.nan, "smooth_time": math.nan, "wall_time": math.nan,
        "trace": "[]", "plan_trace": "[]", "solver": "", "stats": "{}", "mc_runs": 0, "mc_failures": None, "mc_rate": math.nan,
        "mc_ci_low": math.nan, "mc_ci_high": math.nan, "nominal_rate": math.nan, "mc_collisions": None,
        "mc_exits": None, "mc_misses": None,
        "belief_nlp_version": v["belief-nlp"], "solver_version": "", "versions": canonical_json(v),
        "case": canonical_json(case.to_dict()), "finished_at": None})
    return row


def _fail_rows(case: Case, variants, status: str, error: str, common: dict) -> list[dict]:
    rows = []
    for var in variants:
        row = _base_row(case, var)
        row.update(common)
        row.update(status=status, message=error, error=error, finished_at=time.time())
        rows.append(row)
    return rows


def _warm_start(sc, path, case: Case, common: dict):
    """The K-step warm start; when infeasible (or K < edges) one step per edge, recorded."""
    from ..errors import InfeasibleStartError, ValidationError
    from ..smoother.warmstart import warm_start

    t = time.perf_counter()
    try:
        ws = warm_start(sc, path, K=case.K)
    except (InfeasibleStartError, ValidationError) as exc:
        if case.limits.fallback != "edges" or case.K is None or (isinstance(exc, ValidationError)
                                                          and getattr(exc, "field", "K") != "K"):
            raise
        common.update(warm_start_fallback=True, fallback_reason=f"{type(exc).__name__}: {exc}"[:500])
        ws = warm_start(sc, path, K=None)
    common["warm_start_time"] = time.perf_counter() - t
    return ws


def _montecarlo(row: dict, sc, path, case: Case, index: int) -> None:
    from .montecarlo import simulate

    # one random stream per (case, method): reproducible, independent of the executor
    seed = int(case.key, 16) % (2**63) + index
    mc = simulate(sc, path, runs=case.limits.montecarlo, substeps=case.limits.montecarlo_substeps, seed=seed)
    row.update(mc_runs=mc.runs, mc_failures=mc.failures, mc_rate=mc.rate, mc_ci_low=mc.ci_low,
               mc_ci_high=mc.ci_high, nominal_rate=mc.nominal_rate, mc_collisions=mc.collisions,
               mc_exits=mc.exits, mc_misses=mc.misses)


def _smooth_row(row: dict, sc, ws, case: Case, variant: MethodVariant, t_before: float) -> Any:
    """Fill ``row`` with one method's outcome; return the path it scored (or None)."""
    from ..errors import BeliefNLPError
    from ..smoother.driver import smooth

    if variant.method == NO_SMOOTHING:
        rep = ws.report
        row.update(status="warm_start", success=True, message="the warm start itself (no smoothing)",
                   cost=row["warm_start_cost"], iterations=0, build_time=0.0, solve_time=0.0, smooth_time=0.0,
                   wall_time=t_before, safe=bool(rep.safe), min_margin=float(rep.min_margin), worst=str(rep.worst),
                   trace=json.dumps([[t_before, row["warm_start_cost"]]]))
        row.update(control=float(ws.path.control_cost), information=float(ws.path.information))
        return ws.path
    opts = dict(variant.options)
    opts.setdefault("tol", case.limits.tol)
    if case.limits.time_limit is not None:
        opts.setdefault("time_limit", case.limits.time_limit)
    t = time.perf_counter()
    try:
        res = smooth(sc, ws, method=variant.method, alpha=case.alpha, **opts)
    except BeliefNLPError as exc:
        msg = f"{type(exc).__name__}: {exc}"
        row.update(status="error", message=msg[:2000], error=msg[:2000], smooth_time=time.perf_counter() - t)
        return None
    wall = time.perf_counter() - t
    ver = res.verification
    stats = dict(res.stats)
    build = float(res.timings.get("setup", 0.0)) + float(stats.get("build_time", 0.0) or 0.0)
    # anytime trace: best accepted cost so far against the path's total time
    trace, best, clock = [], math.inf, t_before + float(res.timings.get("setup", 0.0))
    for h in res.history:
        clock += float(h.wall_time)
        if h.accepted and h.cost < best:
            best = float(h.cost)
            trace.append([round(clock, 6), best])
    row.update(status=res.status, success=bool(res.success), message=str(res.message)[:2000],
               cost=float(res.cost), control=float(res.control), information=float(res.information),
               iterations=int(res.nit), build_time=build, solve_time=float(res.timings.get("solver", math.nan)),
               smooth_time=wall, wall_time=t_before + wall, safe=bool(res.safe),
               min_margin=float(ver.get("min_margin", math.nan)), worst=str(ver.get("worst", "")),
               solver=str(res.solver), stats=json.dumps(stats, default=str, allow_nan=True),
               trace=json.dumps(trace))
    row["solver_version"] = versions().get(_SOLVER_DIST.get(str(res.solver).upper(), ""), "")
    return res.path


def run_case(case: Case | dict) -> list[dict]:
    """Run ``case`` (a :class:`Case` or its dict); one row per method variant.

    Never raises for a failing case; see the module docstring for the columns.
    """
    from ..errors import BeliefNLPError
    from ..planner import plan

    if isinstance(case, dict):
        from .cases import case_from_dict

        case = case_from_dict(case)
    variants = list(case.methods)
    rows: list[dict] = []
    common: dict[str, Any] = {}
    try:
        with _deadline(case.limits.case_timeout):
            sc = case.scenario.load().with_options(alpha=case.alpha)
            popts = dict(case.planner)
            popts.setdefault("noise", "per_step")     # the smoother's model: one edge = one step
            t = time.perf_counter()
            planned = plan(sc, seed=case.seed, alpha=case.alpha, **popts)
            common["plan_time"] = time.perf_counter() - t
            common["planner_cost"] = float(planned.cost)
            # numba and numpy attempts round apart (same cost distribution, other trees): the row says which ran
            common["planner_backend"] = str(planned.stats.get("backend", ""))
            common["plan_trace"] = json.dumps(planned.cost_trace)
            if not planned.success or planned.path is None:
                return _fail_rows(case, variants, "plan_failed", f"planner: {planned.message}", common)
            try:
                ws = _warm_start(sc, planned.path, case, common)
            except BeliefNLPError as exc:
                return _fail_rows(case, variants, "warm_start_failed", f"{type(exc).__name__}: {exc}", common)
            common["K_used"] = ws.K
            common["warm_start_cost"] = float(ws.path.steering_cost(case.alpha))
            t_before = common["plan_time"] + common["warm_start_time"]
            for i, variant in enumerate(variants):
                row = _base_row(case, variant)
                row.update(common)
                path = _smooth_row(row, sc, ws, case, variant, t_before)
                if path is not None and case.limits.montecarlo > 0:
                    _montecarlo(row, sc, path, case, i)
                row["finished_at"] = time.time()
                rows.append(row)
    except CaseTimeout as exc:
        done = {r["method"] for r in rows}
        return rows + _fail_rows(case, [v for v in variants if v.label not in done], "timeout", str(exc), common)
    except Exception as exc:  # noqa: BLE001 - a study records every failure and goes on
        done = {r["method"] for r in rows}
        msg = f"{type(exc).__name__}: {exc}"[:2000]
        return rows + _fail_rows(case, [v for v in variants if v.label not in done], "error", msg, common)
    return rows


def rows_equal(a: dict, b: dict, rtol: float = 1e-9) -> bool:
    """Two rows agree on every column but the timing ones (floats to ``rtol``)."""
    keys = (set(a) | set(b)) - set(TIMING_COLUMNS)
    for k in keys:
        x, y = a.get(k), b.get(k)
        if isinstance(x, float) and isinstance(y, float):
            if not (x == y or (math.isnan(x) and math.isnan(y)) or abs(x - y) <= rtol * max(abs(x), abs(y))):
                return False
        elif isinstance(x, (float, np.floating)) and y is None or x is None and isinstance(y, float):
            return False
        elif x != y:
            return False
    return True
