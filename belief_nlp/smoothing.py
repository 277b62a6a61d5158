"""``smooth``: the one entry point of every smoothing method."""

from __future__ import annotations

from typing import Any

from .errors import ValidationError
from .nlp.result import SmoothResult
from .nlp.warmstart import WarmStart, warm_start
from .path import BeliefPath
from .scenario import Scenario, load_scenario

__all__ = ["smooth", "METHODS"]

METHODS = ("ccp", "ipopt")


def _validate(max_iter: Any, tol: Any, alpha: Any, time_limit: Any) -> None:
    if max_iter is not None and (not isinstance(max_iter, int) or isinstance(max_iter, bool) or max_iter < 1):
        raise ValidationError("max_iter", f"must be None or a positive integer, got {max_iter!r}")
    if not isinstance(tol, (int, float)) or not tol > 0:
        raise ValidationError("tol", f"must be a number > 0, got {tol!r}")
    if alpha is not None and (not isinstance(alpha, (int, float)) or alpha < 0):
        raise ValidationError("alpha", f"must be None or a number >= 0, got {alpha!r}")
    if time_limit is not None and (not isinstance(time_limit, (int, float)) or time_limit <= 0):
        raise ValidationError("time_limit", f"must be None or a number > 0, got {time_limit!r}")


def smooth(scenario: Scenario | str, path: BeliefPath | WarmStart, method: str = "ccp", K: int | None = None,
           max_iter: int | None = None, tol: float = 1e-4, solver: str = "CLARABEL", alpha: float | None = None, *,
           time_limit: float | None = None, solver_options: dict | None = None,
           keep_iterates: bool = False, progress: bool = False, sensing: str = "minimal",
           **method_options: Any) -> SmoothResult:
    """Smooth a feasible belief path toward a local optimum of the paper's problem.

    Parameters
    ----------
    scenario : Scenario or built-in name / file.
    path : any feasible BeliefPath (planner output, file, hand-made), or a
        :class:`~belief_nlp.nlp.warmstart.WarmStart` already built for it.
    method : "ccp" (convex-concave procedure, paper section IV) or "ipopt"
        (the same model solved by IPOPT through CasADi).
    K : horizon; None = one step per path edge (see :func:`warm_start`).
    max_iter : iteration limit; None = the method's own default (CCP 50,
        IPOPT 3000 -- IPOPT typically needs 200-600 iterations). The paper
        runs 15 CCP iterations; converged CCP answers need 25-45.
    tol : stop when the relative cost decrease of an iteration is below tol.
    solver : conic solver of the CCP subproblems: "CLARABEL" (default; data
        assembled directly and updated in place) or any other conic solver
        CVXPY has installed (e.g. "SCS"), given the same conic data.
    alpha : information weight; None = the scenario's.
    time_limit : wall-time budget in seconds (best feasible iterate returned).
    solver_options : passed to the solver (Clarabel settings, CVXPY solve
        keywords, or IPOPT options for method="ipopt").
    keep_iterates : also return every accepted iterate's path (for animations).
    sensing : how the warm start sets covariances: "minimal" (least sensing
        that keeps the path's means feasible; default) or "path" (keep the
        path's own sensing, add where needed). See :func:`warm_start`.
    progress : show a progress bar.

    Returns
    -------
    SmoothResult. Its path is always feasible and independently verified;
    ``success`` is True when the method converged.
    """
    if isinstance(scenario, str):
        scenario = load_scenario(scenario)
    if method not in METHODS:
        raise ValidationError("method", f"must be one of {METHODS}, got {method!r}")
    _validate(max_iter, tol, alpha, time_limit)
    start = path if isinstance(path, WarmStart) else warm_start(scenario, path, K=K, sensing=sensing)
    if isinstance(path, WarmStart) and K is not None and K != path.K:
        raise ValidationError("K", f"the given warm start has K = {path.K}, not {K}")
    if method == "ccp":
        from .nlp.ccp import ccp

        return ccp(scenario, start, alpha=alpha, max_iter=50 if max_iter is None else max_iter, tol=tol, solver=solver,
                   solver_options=solver_options, time_limit=time_limit, keep_iterates=keep_iterates,
                   progress=progress, **method_options)
    from .nlp.ipopt import ipopt  # noqa: PLC0415 - optional heavy import

    return ipopt(scenario, start, alpha=alpha, max_iter=max_iter, tol=tol, solver_options=solver_options,
                 time_limit=time_limit, keep_iterates=keep_iterates, progress=progress, **method_options)
