"""IG-RRT* within an end-to-end collision-probability budget (issue 20, item 3).

``plan(scenario, risk=Delta)`` (or a scenario whose ``risk`` is set) plans a
warm start for ``smooth(scenario, path, risk=Delta)``: a path whose
certified bound on a collision at the step times,
:func:`belief_nlp.risk.path_risk` ``(scenario, path).step_time``, is at most
Delta, and that the smoother can start from. The planner keeps one
collision level tau (``collision_chi2``) for every transition-hazard pair;
the target containment keeps the scenario's own chi2 (it is not a
collision).

The smoother starts a budgeted run with every one of its K J pairs (K its
horizon: the scenario's ``horizon.K`` when the path fits in it, else one
step per path edge; J the hazards) at one level, the lowest of a ladder
topped by ``RiskBudget(Delta).warm_level(K J)`` whose certified sum fits
(``uniform_level`` for ``allocation="uniform"``, lower;
:mod:`belief_nlp.smoother.budget_start`). A plan whose edges are clear at
``warm_level`` gives it a feasible start (sensing at the cut points only
shrinks the ellipses), and its own certified sum is at most its K J pairs
times g(level) <= 0.9 Delta. K is not known before planning, so the level is found
in rounds:

1. n = J max(horizon, K_est) pairs, K_est = ceil(distance from the start
   mean to the target / the planner's rewiring cap): no path has fewer
   edges when each edge is at most the cap long (edge cost = length +
   alpha * information >= length).
2. Plan at tau = max(warm_level(n), scenario chi2) (never below the
   scenario's chi2, so :func:`belief_nlp.verify` at the scenario's level
   still checks the path; there the budget is met at chi2).
3. The path is taken when its pairs, J max(horizon, K), are at most n and
   its certified sum, recomputed from the path alone, is within Delta.
   Otherwise n = max(J max(horizon, K), 1.25 n) (the level rises every
   round) and plan again, up to :data:`MAX_ROUNDS` rounds.

A round that finds no path ends the search (a higher level only makes
planning harder); so does the time limit, shared by all rounds. Either way
the result has ``success`` False and a message saying that no plan met the
budget, with every round in ``PlanResult.risk``.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import numpy as np

from ..allocation import RiskBudget
from ..errors import ValidationError
from ..scenario import Scenario
from .options import resolve_options
from .result import PlanResult
from .rrt import IGRRTStar

__all__ = ["plan_within_budget", "MAX_ROUNDS"]

#: Planning rounds at rising collision levels before giving up.
MAX_ROUNDS = 4


def _edges_estimate(scenario: Scenario, max_edge: float) -> int:
    """Fewest edges of a path from the start mean into the target when each
    edge is at most ``max_edge`` long (at least 1)."""
    from ..geometry import squared_mahalanobis_distance

    d2 = squared_mahalanobis_distance(scenario.x0[None], np.eye(scenario.dim)[None], [scenario.target])[0, 0]
    return max(1, int(math.ceil(math.sqrt(max(float(d2), 0.0)) / max_edge - 1e-9)))


def plan_within_budget(scenario: Scenario, seed: int | None = 0, alpha: float | None = None,
                       metric: str = "entropy", time_limit: float | None = None, **options: Any) -> PlanResult:
    """IG-RRT* paths until one's certified step-time bound is within ``scenario.risk`` (module doc).

    Parameters
    ----------
    scenario : Scenario
        With ``risk`` set (the budget Delta); ``chi2`` is the target's level.
    seed, alpha, metric, time_limit, **options
        As :func:`belief_nlp.plan` (every round uses the same seed; the time
        limit covers all rounds). ``collision_chi2`` is chosen here.

    Returns
    -------
    PlanResult
        ``risk`` records the budget, the certified bound, the collision level
        and every round; ``success`` is True only for a verified path whose
        certified bound is within the budget and whose level is the warm
        start level of its pairs (module doc).
    """
    if scenario.risk is None:
        raise ValidationError("risk", "the scenario has no risk budget")
    if "collision_chi2" in options or "collision_chi2" in scenario.planner:
        raise ValidationError("collision_chi2", "is chosen from the risk budget; give one of the two")
    budget = RiskBudget(scenario.risk)
    opts = resolve_options(scenario.planner, scenario.alpha, scenario.chi2, seed=seed, alpha=alpha, metric=metric,
                           time_limit=time_limit, **options)
    J = len(scenario.hazards)
    horizon = scenario.K or 0
    n_pairs = J * max(horizon, _edges_estimate(scenario, opts.radius_cap))
    t_start = time.perf_counter()
    rounds: list[dict[str, Any]] = []
    why = ""
    for _ in range(MAX_ROUNDS):
        left = opts.time_limit
        if rounds and left is not None:
            left -= time.perf_counter() - t_start
            if left <= 0:
                why = f"the time limit of {time_limit:g} s was reached"
                break
        level = max(budget.warm_level(n_pairs), scenario.chi2)
        res = IGRRTStar(scenario, seed=seed, alpha=alpha, metric=metric, time_limit=left, collision_chi2=level,
                        **options).plan()
        entry: dict[str, Any] = {"n_pairs": int(n_pairs), "collision_chi2": float(level), "found": res.success,
                                 "K": None, "pairs_needed": None, "bound": None,
                                 "seconds": float(res.timings.get("total", math.nan))}
        rounds.append(entry)
        if not res.success:
            why = f"no path at collision level chi2 = {level:.4g}: {res.message}"
            break
        entry["K"] = int(res.path.K)
        entry["pairs_needed"] = needed = J * max(horizon, entry["K"])
        entry["bound"] = _certified_bound(scenario, res)
        if needed <= n_pairs and entry["bound"] <= budget.budget:
            info = _record(budget, scenario, rounds, met=True)
            msg = (f"{res.message}; certified collision bound {entry['bound']:.3g} <= risk budget "
                   f"{budget.budget:g} with collisions at chi2 = {level:.4g} (target at {scenario.chi2:.4g}), "
                   f"round {len(rounds)} of at most {MAX_ROUNDS}")
            return replace(res, message=msg, risk=info)
        n_pairs = _next_pairs(n_pairs, needed)
    else:
        last = rounds[-1]
        why = (f"after {MAX_ROUNDS} rounds the last path (K = {last['K']}, collisions at chi2 = "
               f"{last['collision_chi2']:.4g} for {last['n_pairs']} pairs) has {last['pairs_needed']} pairs and "
               f"certifies {last['bound']:.3g}")
    msg = f"no plan within the risk budget {budget.budget:g}: {why}"
    info = _record(budget, scenario, rounds, met=False)
    return replace(res, success=False, message=msg, path=None, cost=math.inf, travel=math.nan,
                   information=math.nan, verification=None, risk=info)


def _next_pairs(n_pairs: int, needed: int) -> int:
    """The pair count of the next round: the last path's own (which its
    level must cover), and at least 1.25 times this round's, so that the
    level rises every round (also should a path of few enough pairs ever
    certify more than the budget)."""
    return int(max(needed, math.ceil(1.25 * n_pairs)))


def _certified_bound(scenario: Scenario, res: PlanResult) -> float:
    """The path's certified step-time bound, recomputed from the path alone."""
    from ..risk import path_risk

    return float(path_risk(scenario, res.path).step_time)


def _record(budget: RiskBudget, scenario: Scenario, rounds: list[dict], met: bool) -> dict[str, Any]:
    """``PlanResult.risk``: the budget, what the answer certifies and how it was found."""
    last = rounds[-1]
    return {"budget": budget.budget, "kind": budget.kind, "met": met,
            "bound": last["bound"] if met else None, "collision_chi2": last["collision_chi2"],
            "target_chi2": float(scenario.chi2), "rounds": rounds}
