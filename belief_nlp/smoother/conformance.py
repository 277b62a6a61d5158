"""One conformance suite for every smoothing method (as scikit-learn's
``check_estimator`` is for estimators).

``check_method(method)`` runs a method through the contract of
docs/architecture.md on a small built-in problem and raises AssertionError
naming the first broken rule. The test suite runs it for every registered
method; run it on yours before registering it for others.
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import fields
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import ValidationError
from .registry import Method, resolve_method
from .result import STATUSES, IterationRecord, SmoothResult

__all__ = ["check_method", "small_problem"]


def small_problem():
    """(scenario, path): paper-multi and a safe 5-step path with heavy sensing."""
    from ..path import BeliefPath
    from ..scenario import load_scenario

    sc = load_scenario("paper-multi")
    x = np.array([(0.15, 0.50), (0.15, 0.80), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)])
    S = np.broadcast_to(1e4 * np.eye(2), (5, 2, 2))
    return sc, BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)


def _check(cond: bool, name: str, rule: str) -> None:
    if not cond:
        raise AssertionError(f"method {name!r} breaks the contract: {rule}")


def _check_result(res: SmoothResult, sc, name: str, max_iter: int | None = None) -> None:
    from ..verify import verify

    _check(isinstance(res, SmoothResult), name, "smooth() returns a SmoothResult")
    _check(res.status in STATUSES, name, f"status {res.status!r} is one of STATUSES")
    _check(res.success == (res.status == "converged"), name, "success is True exactly when status is 'converged'")
    _check(res.safe and verify(sc, res.path).safe, name, "the returned path passes independent verification")
    _check(math.isfinite(res.cost) and res.cost <= res.initial_cost * (1 + 1e-12) + 1e-15, name,
           f"the answer never costs more than the warm start ({res.cost} > {res.initial_cost})")
    _check(abs(res.cost - res.path.steering_cost(res.alpha)) <= 1e-8 * max(1.0, abs(res.cost)), name,
           "cost is the paper's objective of the returned path")
    h = res.history
    _check(len(h) >= 1 and h[0].iteration == 0 and h[0].solver_status == "warm_start", name,
           "history[0] is the warm start")
    _check(res.nit == h[-1].iteration, name, "nit is the last history record's iteration number")
    names = {f.name: f.type for f in fields(IterationRecord)}
    for r in h:
        _check(isinstance(r, IterationRecord), name, "history holds IterationRecords")
        _check(isinstance(r.accepted, (bool, np.bool_)), name, "accepted is a bool")
        _check(all(hasattr(r, k) for k in names), name, "records have every IterationRecord field")
        _check(r.solve_time >= 0 and r.wall_time >= 0, name, "solve_time and wall_time are >= 0")
    its = [r.iteration for r in h]
    _check(its == sorted(its) and len(set(its)) == len(its), name, "iterations are numbered increasingly")
    if max_iter is not None:
        _check(res.nit <= max_iter, name, f"max_iter = {max_iter} is honoured (nit = {res.nit})")
    with tempfile.TemporaryDirectory() as tmp:
        back = SmoothResult.load(res.save(Path(tmp) / "r.json"))
    _check(back == res, name, "the result reloads equal from JSON")
    json.dumps(res.stats, default=float)


def check_method(method: str | Method | Callable, problem: tuple | None = None, **options: Any) -> None:
    """Run ``method`` through the contract (module doc); ``problem`` is a
    (scenario, path) pair (default: :func:`small_problem`)."""
    from . import smooth

    m = resolve_method(method)
    sc, path = problem or small_problem()
    name = m.name
    res = smooth(sc, path, method=m, keep_iterates=True, **options)
    _check_result(res, sc, name, m.max_iter)
    from ..verify import verify

    _check(res.iterates is not None and len(res.iterates) >= 1, name, "keep_iterates returns the warm start first")
    _check(all(verify(sc, p).safe for p in res.iterates), name, "every kept iterate is verified safe")
    # limits
    one = smooth(sc, path, method=m, max_iter=1, **options)
    _check_result(one, sc, name, 1)
    quick = smooth(sc, path, method=m, time_limit=1e-3, **options)
    _check_result(quick, sc, name)
    _check(quick.status in ("time_limit", "converged", "max_iter"), name,
           f"an exhausted time limit ends with status time_limit (got {quick.status!r})")
    calls = []
    stopped = smooth(sc, path, method=m, callback=lambda rec: calls.append(rec) or True, **options)
    _check_result(stopped, sc, name)
    _check(len(calls) >= 1 and stopped.status in ("stopped", "converged"), name,
           f"a callback returning True stops the run (got {stopped.status!r} after {len(calls)} calls)")
    # bad input: an unknown option is our error naming it
    try:
        smooth(sc, path, method=m, no_such_option_xyz=1, **options)
    except ValidationError as exc:
        _check(exc.field == "no_such_option_xyz", name, "an unknown option is rejected naming it")
    else:
        _check(False, name, "an unknown option is rejected")
