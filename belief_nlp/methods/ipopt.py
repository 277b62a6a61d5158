"""IPOPT on the exact NLP (:mod:`belief_nlp.model.nlp_form`), through CasADi's
``nlpsol``, from the same warm start as CCP.

The settings and the measurements behind them (adaptive mu, bound push
1e-4, the certificates' proximal term, the restart on a stall, the lifted Q)
are in docs/numerics.md, "IPOPT". When IPOPT stops without converging
(iteration share, failed restoration, a stall of ``stall`` iterations without
a lower feasible cost), it is restarted from the best exactly safe point so
far with a fresh barrier and filter. IPOPT's last point is the answer when
IPOPT converged and the point is exactly safe; otherwise the best exactly
safe recorded iterate is (the driver's rule).

History: one record per IPOPT iteration (restarts continue the count) with
its cost parts; ``accepted`` = satisfies the NLP's constraints to 1e-6;
``min_margin`` = the smallest NLP margin (certificate value of the collision
rows, a lower bound on the squared Mahalanobis clearance minus chi2, and the
target rows); ``kalman_gap`` = the largest Kalman-equality residual.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import casadi as ca
import numpy as np

from ..errors import ValidationError
from ..model import Layout
from ..model.cache import MemoryCache, problem_key
from ..model.nlp_form import FORMULATIONS, NLPProblem, build_nlp
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.policy import DEFAULT_POLICY
from ..smoother.registry import Method, Option, register
from ..smoother.result import STATUSES, IterationRecord
from .ipopt_recorder import Recorder

__all__ = ["run", "DEFAULT_IPOPT_OPTIONS", "map_status", "clear_cache"]

log = logging.getLogger("belief_nlp.smoother")

#: IPOPT settings used unless ``solver_options`` overrides them (docs/numerics.md).
DEFAULT_IPOPT_OPTIONS: dict[str, Any] = {
    "mu_strategy": "adaptive",
    "mu_oracle": "loqo",
    "bound_push": 1e-4,
    "bound_frac": 1e-4,
    "constr_viol_tol": 1e-8,
    "print_level": 0,
    "sb": "yes",
}

_CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
_MAX_ITER = {"Maximum_Iterations_Exceeded"}
_TIME = {"Maximum_CpuTime_Exceeded", "Maximum_WallTime_Exceeded"}

_CACHE = MemoryCache(6)


def map_status(ipopt_status: str) -> str:
    """IPOPT's return status -> one of :data:`STATUSES` (before the exact check)."""
    if ipopt_status in _CONVERGED:
        return "converged"
    if ipopt_status in _MAX_ITER:
        return "max_iter"
    if ipopt_status in _TIME:
        return "time_limit"
    return "ipopt_failed"


def clear_cache() -> None:
    """Drop every cached NLP / IPOPT instance."""
    _CACHE.clear()


def _ipopt_options(solver_options: dict, tol: float) -> dict:
    # IPOPT's own max_iter stays out of the options (and so out of the cache
    # key): the recorder enforces the run's iteration budget, one solver
    # instance serves every budget; a user's "max_iter" option still applies
    opts = dict(DEFAULT_IPOPT_OPTIONS)
    opts["max_iter"] = 10**7
    opts["tol"] = float(tol)
    for key, value in solver_options.items():
        opts[key[len("ipopt."):] if key.startswith("ipopt.") else key] = value
    return opts


def _solver(problem: SmoothingProblem, opts: dict, formulation: str, margin: float, regularisation: float,
            candidates: int, cache: bool) -> tuple[NLPProblem, Any, Recorder, str]:
    """NLP, nlpsol instance and recorder, from the cache when the model and options match."""
    key = problem_key(problem.model.data, margin, f"ipopt:{formulation}:{regularisation}:{sorted(opts.items())!r}")
    entry = _CACHE.get(key) if cache else None
    if entry is not None:
        return (*entry, "memory")
    nlp = build_nlp(problem.model, formulation, margin=margin, regularisation=regularisation)
    recorder = Recorder(nlp, problem.model.data.alpha, keep=candidates, bar=None, stall=0)
    try:
        solver = ca.nlpsol("belief_nlp_ipopt", "ipopt", {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                           {"ipopt": opts, "print_time": False, "iteration_callback": recorder,
                            "error_on_fail": False, "show_eval_warnings": False})
    except RuntimeError as exc:  # bad option names or values
        raise ValidationError("solver_options", f"IPOPT refused them: {str(exc).splitlines()[-1][:200]}") from None
    if cache:
        _CACHE.put(key, (nlp, solver, recorder))
    return nlp, solver, recorder, "built"


def _safe_points(problem: SmoothingProblem, nlp: NLPProblem, recorder: Recorder, z_end: np.ndarray | None,
                 converged: bool) -> list[tuple[float, Layout, str, int | None]]:
    """Exactly safe points among IPOPT's last point and the recorded feasible
    iterates, as (cost, point, description, iteration or None for the last
    point); when IPOPT converged and its last point is safe, that point alone."""
    pool = [(None, z_end)] if z_end is not None and np.all(np.isfinite(z_end)) else []
    pool += [(it, zv) for _, it, zv in recorder.best]
    found = []
    for it, zv in pool:
        try:
            chk = problem.check(problem.model.tighten(nlp.unpack(zv)))
        except np.linalg.LinAlgError:
            continue
        if not chk.safe:
            continue
        where = "IPOPT's final point" if it is None else f"IPOPT iterate {it} (the best feasible one)"
        found.append((problem.model.cost(chk.point)[0], chk.point, where, it))
        if it is None and converged:
            return found
    return found


def _record_attempt(problem: SmoothingProblem, nlp: NLPProblem, recorder: Recorder, start: int,
                    found: list, ipopt_status: str) -> None:
    """History records of one attempt's iterations (cost parts in one batch)."""
    rows, zs = recorder.rows[start:], recorder.zs[start:]
    if not rows:
        return
    D = problem.model.data
    Z = np.stack(zs, axis=1)
    ctrls, infos, _ = (np.asarray(v).ravel() for v in nlp.parts.map(Z.shape[1])(Z, recorder.pvs[-1]))
    safe = {it: z for _, z, _, it in found if it is not None}
    last = rows[-1][0]
    final = next((z for _, z, _, it in found if it is None), None)
    for (it, mmin, viol, dt, kgap), ctrl, info in zip(rows, ctrls, infos):
        rec = IterationRecord(it, float(ctrl + D.alpha * info), float(ctrl), float(info),
                              ipopt_status if it == last else "", dt, 0.0, dt, 1, accepted=viol <= 1e-6,
                              min_margin=mmin, kalman_gap=kgap)
        point = final if it == last and final is not None else safe.get(it)
        problem.record(rec, point if rec.accepted else None)


def run(problem: SmoothingProblem, *, formulation: str = "cholesky", regularisation: float = 1e-4,
        margin: float = DEFAULT_POLICY.nlp, restarts: int = 1, stall: int = 300, candidates: int = 5,
        cache: bool = True) -> Outcome:
    """IPOPT from the problem's start (module doc; options in :data:`METHOD`)."""
    opts = _ipopt_options(problem.solver_options, problem.tol)
    max_iter = min(int(opts["max_iter"]), problem.max_iter)
    if problem.out_of_time():                      # the warm start used the budget up
        return Outcome("time_limit", f"{STATUSES['time_limit']} (before IPOPT started)", None, "IPOPT")
    t_build = time.perf_counter()
    nlp, solver, recorder, origin = _solver(problem, opts, formulation, margin, regularisation,
                                            max(int(candidates), 0), cache)
    bar = problem.progress_bar("IPOPT")
    recorder.reset(keep=max(int(candidates), 0), bar=bar, stall=stall if restarts else 0)
    stats: dict[str, Any] = {"build": origin, "build_time": time.perf_counter() - t_build, "attempts": []}
    used, attempts, ipopt_status = 0, 0, "not run"
    z_start, best, answer = problem.start, (problem.cost0, problem.start, "the warm start"), None
    while True:
        remaining = max_iter - used
        budget = remaining if attempts >= restarts else max(1, remaining - remaining // 3)
        if problem.out_of_time():
            ipopt_status = "Maximum_WallTime_Exceeded"
            break
        pv = nlp.anchor(z_start)
        n_rows = len(recorder.rows)
        recorder.begin(pv, budget, problem.deadline)
        t_solve = time.perf_counter()
        try:
            sol = solver(x0=nlp.pack(z_start), p=pv, lbx=nlp.lbz, ubx=nlp.ubz, lbg=nlp.lbg, ubg=nlp.ubg)
            z_end = np.asarray(sol["x"]).ravel()
        except RuntimeError as exc:   # CasADi raises on some IPOPT exceptions
            log.warning("IPOPT raised: %s", exc)
            z_end = None
        st = solver.stats()
        ipopt_status = str(st.get("return_status", "unknown"))
        if ipopt_status == "User_Requested_Stop" and recorder.stop_reason:
            ipopt_status = {"max_iter": "Maximum_Iterations_Exceeded", "time_limit": "Maximum_WallTime_Exceeded",
                            "stalled": "Stalled"}[recorder.stop_reason]
        n_it = int(st.get("iter_count", 0))
        stats["attempts"].append({"return_status": ipopt_status, "iter_count": n_it,
                                  "wall_time": time.perf_counter() - t_solve,
                                  "t_proc_total": float(st.get("t_proc_total", float("nan")))})
        used += n_it
        attempts += 1
        status = map_status(ipopt_status)
        found = _safe_points(problem, nlp, recorder, z_end, status == "converged")
        _record_attempt(problem, nlp, recorder, n_rows, found, ipopt_status)
        if status == "converged" and found and found[0][3] is None:
            answer = found[0]
            break
        for cand in found:
            if cand[0] < best[0]:
                best = cand[:3]
        if attempts > restarts or status == "time_limit" or used >= max_iter or best[1] is z_start \
                or problem.stop_requested:
            break
        log.info("IPOPT %s after %d iterations; restarting from %s", ipopt_status, used, best[2])
        z_start = best[1]
    if bar is not None:
        bar.close()
    status = map_status(ipopt_status)
    stats.update(return_status=ipopt_status, iter_count=used)
    tries = f" in {attempts} attempts ({', '.join(a['return_status'] for a in stats['attempts'])})" \
        if attempts > 1 else ""
    message = f"IPOPT returned {ipopt_status} after {used} iterations{tries}"
    if status == "converged" and answer is None:
        status = "infeasible_iterate"
        message += f"; its last point failed the exact safety check ({STATUSES[status]})"
    elif status != "converged":
        message += f" ({STATUSES[status]})"
    if problem.stop_requested and status != "converged":
        status, message = "stopped", STATUSES["stopped"]
    return Outcome(status, message, answer[1] if answer else None, "IPOPT", stats)


def _nonneg(v: Any) -> str | None:
    return None if isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0 else "must be a number >= 0"


def _count(v: Any) -> str | None:
    return None if isinstance(v, int) and not isinstance(v, bool) and v >= 0 else "must be an integer >= 0"


METHOD = register(Method(
    name="ipopt", run=run, max_iter=3000, default_solver="IPOPT",
    check_solver=lambda s: None if s.upper() == "IPOPT" else f"method 'ipopt' runs IPOPT only, got {s!r}",
    description="IPOPT on the exact NLP (S = L L^T, Q = M M^T, Kalman equality), exact Hessian",
    iteration="one IPOPT iteration",
    options={
        "formulation": Option("cholesky", f"NLP variables: one of {FORMULATIONS}",
                              lambda v: None if v in FORMULATIONS else f"must be one of {FORMULATIONS}"),
        "regularisation": Option(1e-4, "weight of the certificates' proximal term", _nonneg),
        "margin": Option(DEFAULT_POLICY.nlp, "relative clearance margin kept in the NLP's collision rows", _nonneg),
        "restarts": Option(1, "restarts from the best safe point after an unconverged stop", _count),
        "stall": Option(300, "iterations without a lower feasible cost that end an attempt", _count),
        "candidates": Option(5, "feasible iterates kept as fallback candidates", _count),
        "cache": Option(True, "reuse the NLP and IPOPT instance of an earlier call with the same model",
                        lambda v: None if isinstance(v, bool) else "must be True or False"),
    },
))
