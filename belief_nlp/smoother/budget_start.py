"""Warm starts inside a risk budget (:class:`belief_nlp.allocation.RiskBudget`).

A path is made feasible by :func:`.warmstart.warm_start` at one collision
level for every pair. Under a budget that level is chosen so that the
certified bound fits:

* uniform allocation: the budget's uniform level, g^-1(Delta / (K J));
* optimal allocation, step-time bound: the lowest level of a ladder (the
  uniform level at 90 % of Delta, then x0.9 per rung, and the scenario's
  chi2) whose certified step-time bound is within 97 % of Delta. Lower levels
  sense less, so this is the start nearest the optimum; the highest level
  that fits sensed up to 6x as much, and IPOPT's first steps from such
  starts failed (docs/numerics.md, "Risk allocation in the NLP polish");
* continuous-time bound: the step-time start, then every posterior scaled
  by the largest factor that makes the per-pair surrogate fit.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..allocation import RiskBudget, tail
from ..errors import InfeasibleStartError
from ..path import BeliefPath
from ..risk import path_risk, surrogate_clearance
from ..scenario import Scenario
from .warmstart import WarmStart, scaled_posteriors, sharpened, warm_start

__all__ = ["budget_warm_start"]

#: the share of the budget a warm start may spend (the rest keeps it strictly inside)
START_SHARE = 0.97
#: a continuous-time start scales its posteriors by at least 2^-SHARPEN_OCTAVES
SHARPEN_OCTAVES = 24.0


def budget_warm_start(scenario: Scenario, path: BeliefPath, K: int | None, sensing: str,
                      budget: RiskBudget) -> WarmStart:
    """The warm start of ``path`` at K inside ``budget`` (module doc); raises
    InfeasibleStartError when none fits, saying what the best one spends."""
    n_pairs = (path.K if K is None else K) * len(scenario.hazards)
    if budget.kind == "continuous":
        return _continuous(scenario, path, K, sensing, budget, n_pairs)
    uniform = budget.allocation == "uniform"
    levels = [budget.uniform_level(n_pairs)] if uniform else _ladder(scenario, budget, n_pairs)
    errors: list[InfeasibleStartError] = []
    memo: dict[float, tuple[str, WarmStart | None, float]] = {}

    def rung(chi2: float) -> tuple[str, WarmStart | None, float]:
        # memoised: the fallback below revisits the rungs the bisection built
        if chi2 not in memo:
            memo[chi2] = _rung(chi2)
        return memo[chi2]

    def _rung(chi2: float) -> tuple[str, WarmStart | None, float]:
        try:
            # unverified, as every start of smooth(): the path returned is verified at its own levels
            warm = warm_start(scenario, path, K=K, sensing=sensing, chi2=chi2, verify_start=False)
        except InfeasibleStartError as exc:
            errors.append(exc)
            return "infeasible", None, float("inf")
        if uniform:            # the uniform level spends the budget by construction
            return "fits", warm, float("nan")
        bound = path_risk(scenario, warm.path, warm.lam).step_time
        return ("fits" if bound <= START_SHARE * budget.budget else "over"), warm, bound

    last, first_over = _last_not_over(levels, rung)
    if last is not None and last[0] == "fits":
        return last[1]
    # an out-of-order ladder (not seen: a lower level never needs more sensing) could hide
    # a rung that fits from the bisection: before giving up, every rung from the top
    for chi2 in levels:
        state, warm, bound = rung(chi2)
        if state == "fits":
            return warm
        if state == "over":          # the highest rung that clears: the least any rung spends
            first_over = (state, warm, bound)
            break
    why = (f"the best warm start's certified bound is {first_over[2]:.3g}" if first_over is not None
           else f"{_every_pair(budget, levels[-1], n_pairs)}: {errors[0] if errors else 'no warm start'}")
    err = errors[0] if errors else None
    raise InfeasibleStartError(f"no warm start meets the risk budget {budget.budget:g} ({why}; plan with "
                               f"risk={budget.budget:g} or give a larger budget)",
                               getattr(err, "transition", None), getattr(err, "obstacle", None))


def _every_pair(budget: RiskBudget, level: float, n_pairs: int) -> str:
    """What a failed start at one level for every pair tried (error messages)."""
    if budget.allocation == "uniform":
        return (f"under the uniform allocation every pair at level {level:.4g} ({budget.budget / n_pairs:.3g} each; "
                f"allocation='optimal' may fit)")
    return f"every pair at level {level:.4g}"


def _ladder(scenario: Scenario, budget: RiskBudget, n_pairs: int) -> list[float]:
    """The optimal allocation's start levels, descending: the uniform level at
    90 % of the budget, x0.9 per rung (13 rungs), and the scenario's chi2 when
    it is below the top."""
    top = budget.warm_level(n_pairs)
    return sorted({top * 0.9**i for i in range(13)} | ({scenario.chi2} if scenario.chi2 < top else set()),
                  reverse=True)


def _last_not_over(levels: list[float], rung: Callable[[float], tuple]) -> tuple[tuple | None, tuple | None]:
    """Bisection over ``levels`` (descending) for the boundary of a ladder that
    reads infeasible (too high to clear), then fits, then over the budget
    (too little sensing): (the last rung not over, the first rung over), each
    ``rung``'s (state, warm start, bound) or None. Four or five warm starts
    instead of up to 14."""
    lo, hi, seen = -1, len(levels), {}
    while hi - lo > 1:
        mid = (lo + hi) // 2
        seen[mid] = rung(levels[mid])
        if seen[mid][0] == "over":
            hi = mid
        else:
            lo = mid
    return seen.get(lo), seen.get(hi)


def _continuous(scenario: Scenario, path: BeliefPath, K: int | None, sensing: str, budget: RiskBudget,
                n_pairs: int) -> WarmStart:
    """A warm start for a continuous-time budget. The surrogate asks each level
    under Sigma_k = P_prior_{k-1} + W, which only sensing before step k - 1
    shrinks: the step-time warm start at the budget's level, then with every
    posterior scaled by the largest factor f <= 1 (the least added sensing)
    that makes the surrogate fit -- every pair clear of the uniform level
    (uniform allocation), or the surrogate's sum within 97 % of the budget
    (optimal). f is found by bisection on log2 f in [-24, 0]; halving it
    until the surrogate fit (before session 18) sensed up to 2x too much in
    every step, and IPOPT failed from 2 of 7 such starts on paper-multi."""
    # the uniform level, or the highest rung of the step-time ladder whose start exists (pairs near
    # a hazard then spend more of the budget, the sharpening below pays for it); unverified, as
    # every start of smooth(): the sharpened start is verified, the path returned too
    levels = [budget.uniform_level(n_pairs)] if budget.allocation == "uniform" else _ladder(scenario, budget, n_pairs)
    for i, base in enumerate(levels):
        try:
            warm = warm_start(scenario, path, K=K, sensing=sensing, chi2=base, verify_start=False)
            break
        except InfeasibleStartError as exc:
            if i == len(levels) - 1:
                raise InfeasibleStartError(f"no warm start meets the continuous-time risk budget {budget.budget:g} "
                                           f"({_every_pair(budget, base, n_pairs)}: {exc})", exc.transition,
                                           exc.obstacle) from exc
    spent = [float("inf")]
    worst: list = [None]

    def fits(exponent: float) -> bool:
        clear = surrogate_clearance(scenario, scaled_posteriors(scenario, warm.path, 2.0**exponent))
        spent[0] = float(np.sum(budget.factor * tail(clear)))
        worst[0] = np.unravel_index(int(np.argmin(clear)), clear.shape), float(budget.factor * tail(clear.min()))
        if budget.allocation == "uniform":
            return bool(np.all(clear >= base * (1 + 1e-3)))
        return spent[0] <= START_SHARE * budget.budget

    if fits(0.0):
        return warm
    if not fits(-SHARPEN_OCTAVES):
        (k, j), risk = worst[0]
        hazard = scenario.hazards[int(j)].name
        if budget.allocation == "uniform":
            # the sum may be well inside the budget: it is one pair's share that no sensing meets
            why = (f"under the uniform allocation each transition-hazard pair gets {budget.budget / n_pairs:.3g}, "
                   f"and with all the sensing transition {int(k) + 1} against {hazard} spends {risk:.3g} (the sum "
                   f"{spent[0]:.3g}); use allocation='optimal', a larger budget or a path further from {hazard}")
        else:
            why = (f"with all the sensing the surrogate spends {spent[0]:.3g}, transition {int(k) + 1} against "
                   f"{hazard} the most ({risk:.3g}): the means pass too close to a hazard for the noise W; give a "
                   f"larger budget or a path further from the hazards")
        raise InfeasibleStartError(f"no warm start meets the continuous-time risk budget {budget.budget:g} ({why})",
                                   int(k) + 1, hazard)
    lo, hi = -SHARPEN_OCTAVES, 0.0              # fits at lo, not at hi
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return sharpened(scenario, warm, 2.0**lo, base)
