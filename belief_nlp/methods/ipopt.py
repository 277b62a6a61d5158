"""IPOPT on the exact NLP (:mod:`belief_nlp.model.nlp_form`), through CasADi's
``nlpsol``, from the same warm start as CCP.

Two stages (docs/numerics.md, "IPOPT"):

1. the "logchol" NLP: S_k = L_k L_k^T with L_k,ii = exp(w) >= ``floor`` keeps
   the iterates off the L = 0 saddle, where every gradient in L vanishes and
   a minimal-sensing warm start sits; adaptive mu with mu_min 1e-7;
2. a polish of at most ``polish`` iterations on the exact "cholesky" NLP from
   that answer, with the sensing directions held at the floor switched off
   (:meth:`~belief_nlp.model.nlp_form.NLPProblem.without_sensing`); its
   answer replaces stage 1's when it converged, is exactly safe and is not
   costlier.

When a stage stops without converging (iteration share, failed restoration,
a stall of ``stall`` iterations without a lower feasible cost), IPOPT is
restarted from the best exactly safe point so far with a fresh barrier and
filter. IPOPT's last point is the answer when IPOPT converged and the point
is exactly safe; otherwise the best exactly safe recorded iterate is (the
driver's rule).

History: one record per IPOPT iteration (stages and restarts continue the
count) with its cost parts; ``accepted`` = satisfies the NLP's constraints to
1e-6; ``min_margin`` = the smallest NLP margin (certificate value of the
collision rows, a lower bound on the squared Mahalanobis clearance minus
chi2, and the target rows); ``kalman_gap`` = the largest Kalman-equality
residual. Stats: ``attempts`` (formulation, return status, iterations,
restoration iterations read from IPOPT's log, CPU and wall seconds),
``iter_count``, ``restoration``, ``cpu_time``, ``polish_status``.
"""

from __future__ import annotations

import atexit
import logging
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable

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

#: changes for the floored log-Cholesky stage and for the polish after it
LOGCHOL_IPOPT_OPTIONS: dict[str, Any] = {"mu_min": 1e-7}
POLISH_IPOPT_OPTIONS: dict[str, Any] = {"mu_strategy": "monotone", "mu_init": 1e-8}

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


def _ipopt_options(solver_options: dict, tol: float, formulation: str, polish: bool = False) -> dict:
    # IPOPT's own max_iter stays out of the options (and so out of the cache
    # key): the recorder enforces the run's iteration budget, one solver
    # instance serves every budget; a user's "max_iter" option still applies
    opts = dict(DEFAULT_IPOPT_OPTIONS)
    if formulation == "logchol":
        opts.update(LOGCHOL_IPOPT_OPTIONS)
    if polish:
        opts.update(POLISH_IPOPT_OPTIONS)
    opts["max_iter"] = 10**7
    opts["tol"] = float(tol)
    for key, value in solver_options.items():
        opts[key[len("ipopt."):] if key.startswith("ipopt.") else key] = value
    return opts


_RESTO = re.compile(rb"^\s*\d+r\s", re.M)
_LOG_DIR: list[str] = []


def _log_file() -> str:
    """A fresh IPOPT log file in a per-process folder removed at exit. CasADi's
    IPOPT statistics carry no restoration flag; the log's iteration table
    marks restoration iterations with "r", so each solve reads its part."""
    if not _LOG_DIR:
        _LOG_DIR.append(tempfile.mkdtemp(prefix="belief_nlp_ipopt_"))
        atexit.register(shutil.rmtree, _LOG_DIR[0], True)
    fd, path = tempfile.mkstemp(suffix=".log", dir=_LOG_DIR[0])
    os.close(fd)
    return path


def _restoration_count(log_path: str, offset: int) -> int:
    """Restoration iterations in the IPOPT log written after ``offset``."""
    try:
        with open(log_path, "rb") as fh:
            fh.seek(offset)
            return len(_RESTO.findall(fh.read()))
    except OSError:
        return 0


def _log_size(log_path: str) -> int:
    try:
        return os.path.getsize(log_path)
    except OSError:
        return 0


def _solver(problem: SmoothingProblem, opts: dict, formulation: str, margin: float, regularisation: float,
            floor: float, candidates: int, cache: bool) -> tuple[NLPProblem, Any, Recorder, str]:
    """NLP, nlpsol instance and recorder, from the cache when the model and options match."""
    key = problem_key(problem.model.data, margin,
                      f"ipopt:{formulation}:{regularisation}:{floor}:{sorted(opts.items())!r}")
    entry = _CACHE.get(key) if cache else None
    if entry is not None:
        return (*entry, "memory")
    nlp = build_nlp(problem.model, formulation, margin=margin, regularisation=regularisation, floor=floor)
    recorder = Recorder(nlp, problem.model.data.alpha, keep=candidates, bar=None, stall=0)
    log_path = _log_file()
    recorder.log_path = log_path
    try:
        solver = ca.nlpsol("belief_nlp_ipopt", "ipopt", {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                           {"ipopt": {**opts, "output_file": log_path, "file_print_level": 5}, "print_time": False, "iteration_callback": recorder,
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


@dataclass
class _Stage:
    """What one NLP stage (one formulation, its attempts) ended with."""

    ipopt_status: str = "not run"
    used: int = 0
    answer: tuple | None = None          # (cost, point, where, None): converged and exactly safe
    best: tuple | None = None            # lowest-cost exactly safe point seen (cost, point, where)
    attempts: list = field(default_factory=list)
    build: str = ""
    build_time: float = 0.0


def _solve_stage(problem: SmoothingProblem, stage: _Stage, *, formulation: str, opts: dict, margin: float,
                 regularisation: float, floor: float, candidates: int, cache: bool, start: Layout,
                 max_iter: int, restarts: int, stall: int, offset: int, bar: Any,
                 bounds: Callable | None = None) -> _Stage:
    """IPOPT on one formulation from ``start``: attempts with restarts from the
    best exactly safe point (module doc), at most ``max_iter`` iterations.
    ``bounds(nlp, point)`` -> (z0, lbz, ubz) replaces the NLP's own start and bounds."""
    t_build = time.perf_counter()
    nlp, solver, recorder, stage.build = _solver(problem, opts, formulation, margin, regularisation, floor,
                                                 max(int(candidates), 0), cache)
    stage.build_time = time.perf_counter() - t_build
    recorder.reset(keep=max(int(candidates), 0), bar=bar, stall=stall if restarts else 0)
    recorder.offset = offset
    z_start = start
    stage.best = (problem.model.cost(start)[0], start, "the stage's start")
    n_attempts = 0
    while True:
        remaining = max_iter - stage.used
        budget = remaining if n_attempts >= restarts else max(1, remaining - remaining // 3)
        if problem.out_of_time() or remaining <= 0:
            stage.ipopt_status = "Maximum_WallTime_Exceeded" if problem.out_of_time() else \
                "Maximum_Iterations_Exceeded"
            break
        pv = nlp.anchor(z_start)
        n_rows = len(recorder.rows)
        recorder.begin(pv, budget, problem.deadline)
        t_solve, c_solve, log_at = time.perf_counter(), time.process_time(), _log_size(recorder.log_path)
        try:
            x0, lbx, ubx = bounds(nlp, z_start) if bounds else (nlp.pack(z_start), nlp.lbz, nlp.ubz)
            sol = solver(x0=x0, p=pv, lbx=lbx, ubx=ubx, lbg=nlp.lbg, ubg=nlp.ubg)
            z_end = np.asarray(sol["x"]).ravel()
        except RuntimeError as exc:   # CasADi raises on some IPOPT exceptions
            log.warning("IPOPT raised: %s", exc)
            z_end = None
        st = solver.stats()
        status_raw = str(st.get("return_status", "unknown"))
        if status_raw == "User_Requested_Stop" and recorder.stop_reason:
            status_raw = {"max_iter": "Maximum_Iterations_Exceeded", "time_limit": "Maximum_WallTime_Exceeded",
                          "stalled": "Stalled"}[recorder.stop_reason]
        stage.ipopt_status = status_raw
        n_it = int(st.get("iter_count", 0))
        stage.attempts.append({"formulation": formulation, "return_status": status_raw, "iter_count": n_it,
                               "restoration": _restoration_count(recorder.log_path, log_at), "wall_time": time.perf_counter() - t_solve,
                               "cpu_time": time.process_time() - c_solve})
        stage.used += n_it
        n_attempts += 1
        status = map_status(status_raw)
        found = _safe_points(problem, nlp, recorder, z_end, status == "converged")
        _record_attempt(problem, nlp, recorder, n_rows, found, status_raw)
        if status == "converged" and found and found[0][3] is None:
            stage.answer = found[0]
            break
        for cand in found:
            if cand[0] < stage.best[0]:
                stage.best = cand[:3]
        if n_attempts > restarts or status == "time_limit" or stage.used >= max_iter \
                or stage.best[1] is z_start or problem.stop_requested:
            break
        log.info("IPOPT %s after %d iterations; restarting from %s", status_raw, stage.used, stage.best[2])
        z_start = stage.best[1]
    return stage


def run(problem: SmoothingProblem, *, formulation: str = "logchol", floor: float = 1e-2, polish: int = 50,
        regularisation: float = 1e-4, margin: float = DEFAULT_POLICY.nlp, restarts: int = 1, stall: int = 300,
        candidates: int = 5, cache: bool = True) -> Outcome:
    """IPOPT from the problem's start (module doc; options in :data:`METHOD`)."""
    opts = _ipopt_options(problem.solver_options, problem.tol, formulation)
    max_iter = min(int(opts.pop("max_iter")), problem.max_iter)
    if problem.out_of_time():                      # the warm start used the budget up
        return Outcome("time_limit", f"{STATUSES['time_limit']} (before IPOPT started)", None, "IPOPT")
    bar = problem.progress_bar("IPOPT")
    common = dict(margin=margin, regularisation=regularisation, candidates=candidates, cache=cache, bar=bar,
                  stall=stall)
    first = _solve_stage(problem, _Stage(), formulation=formulation, floor=floor, opts=opts, start=problem.start,
                         max_iter=max_iter, restarts=restarts, offset=0, **common)
    stages = [first]
    if formulation == "logchol" and polish and first.answer is not None and first.used < max_iter \
            and not problem.out_of_time() and not problem.stop_requested:
        # the floored answer senses >= floor^2 in every direction: switch the
        # directions held at the floor off and free the rest on the exact
        # Cholesky NLP (docs/numerics.md, "IPOPT")
        polish_opts = _ipopt_options(problem.solver_options, problem.tol, "cholesky", polish=True)
        polish_opts.pop("max_iter")
        second = _solve_stage(problem, _Stage(), formulation="cholesky", floor=floor, opts=polish_opts,
                              bounds=lambda nlp, lay: nlp.without_sensing(lay, floor), start=first.answer[1],
                              max_iter=min(int(polish), max_iter - first.used), restarts=0,
                              offset=first.used, **common)
        stages.append(second)
    if bar is not None:
        bar.close()
    return _outcome(problem, stages)


def _outcome(problem: SmoothingProblem, stages: list[_Stage]) -> Outcome:
    """The run's status, answer and raw stats from its stages."""
    first, last = stages[0], stages[-1]
    attempts = [a for s in stages for a in s.attempts]
    used = sum(s.used for s in stages)
    stats: dict[str, Any] = {
        "build": first.build, "build_time": sum(s.build_time for s in stages), "attempts": attempts,
        "return_status": first.ipopt_status, "iter_count": used,
        "restoration": sum(a["restoration"] for a in attempts),
        "cpu_time": sum(a["cpu_time"] for a in attempts)}
    status = map_status(first.ipopt_status)
    message = f"IPOPT returned {first.ipopt_status} after {first.used} iterations"
    if len(first.attempts) > 1:
        message += f" in {len(first.attempts)} attempts ({', '.join(a['return_status'] for a in first.attempts)})"
    answer = first.answer
    if len(stages) > 1:
        stats["polish_status"] = last.ipopt_status
        if last.answer is not None and last.answer[0] <= first.answer[0]:
            answer = last.answer
            message += f"; polished on the exact Cholesky NLP in {last.used} iterations"
        else:
            message += f"; polish ended {last.ipopt_status} after {last.used} iterations (not lower; not used)"
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
    description="IPOPT on the exact NLP (S = L L^T, Q = M M^T, Kalman equality), exact Hessian; "
                "floored log-Cholesky stage, then an exact-Cholesky polish",
    iteration="one IPOPT iteration",
    options={
        "formulation": Option("logchol", f"NLP variables: one of {FORMULATIONS}",
                              lambda v: None if v in FORMULATIONS else f"must be one of {FORMULATIONS}"),
        "floor": Option(1e-2, "smallest diagonal entry of L in the 'logchol' stage (scaled units)",
                        lambda v: None if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0
                        else "must be a number > 0"),
        "polish": Option(50, "iteration cap of the polish after the 'logchol' stage (0: none)", _count),
        "regularisation": Option(1e-4, "weight of the certificates' proximal term", _nonneg),
        "margin": Option(DEFAULT_POLICY.nlp, "relative clearance margin kept in the NLP's collision rows", _nonneg),
        "restarts": Option(1, "restarts from the best safe point after an unconverged stop", _count),
        "stall": Option(300, "iterations without a lower feasible cost that end an attempt", _count),
        "candidates": Option(5, "feasible iterates kept as fallback candidates", _count),
        "cache": Option(True, "reuse the NLP and IPOPT instance of an earlier call with the same model",
                        lambda v: None if isinstance(v, bool) else "must be True or False"),
    },
))
