"""``plan``: the planners' one entry point (IG-RRT* by default, or an OMPL planner by name)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..allocation import RiskBudget
from ..errors import ValidationError
from ..scenario import Scenario, load_scenario
from .ompl_baseline import DEFAULT_PLANNER, parse_planner, plan_ompl
from .budget import plan_within_budget
from .result import PlanResult
from .rrt import IGRRTStar

__all__ = ["plan"]


def plan(scenario: Scenario, n_nodes: int | None = None, seed: int | None = 0, alpha: float | None = None,
         metric: str = "entropy", noise: str | None = None, time_limit: float | None = None,
         branch_and_bound: bool | None = None, planner: str = DEFAULT_PLANNER, risk: float | None = None,
         **options: Any) -> PlanResult:
    """Plan a minimum-sensing belief path with IG-RRT* (or the OMPL baseline).

    Parameters
    ----------
    scenario : Scenario or str
        The planning problem, or a built-in name / scenario file for
        :func:`belief_nlp.load_scenario`.
    n_nodes : int, optional
        Nodes in the final tree (root included); None: the scenario's
        ``[planner]`` value, else 500. IG-RRT* only.
    seed : int or None, optional
        Seed of the random generator; the same seed gives the same result.
    alpha : float, optional
        Information weight; None uses ``scenario.alpha``.
    metric : {"entropy", "wasserstein", "hellinger"}, optional
        The information metric of an edge; ``"entropy"`` (default) in nats.
    noise : {"per_metre", "per_step"}, optional
        ``"per_metre"`` (P_hat = P + W_rate ||dx||, the authors') or
        ``"per_step"`` (P_hat = P + W per edge, whatever its length, the
        smoother's model); None uses the scenario's ``[planner] noise``, else
        per_metre. paper-multi says per_step, so ``smooth(sc, plan(sc).path)``
        works as it is.
    time_limit : float, optional
        Wall-time budget in seconds; None for no limit (OMPL planners: 1 s).
    branch_and_bound : bool, optional
        Prune nodes that cannot improve on the best path (None: on). IG-RRT* only.
    planner : str, optional
        ``"igrrt"`` (IG-RRT*, the default) or ``"ompl:<Class>"``, any geometric
        planner of OMPL (``"ompl:RRTstar"``, ``"ompl:InformedRRTstar"``,
        ``"ompl:AORRTC"``, ...): the mean path by OMPL under this library's
        exact transition checks, then the least sensing that keeps it safe
        (:mod:`~belief_nlp.planner.ompl_baseline`; needs the ``ompl`` extra).
    risk : float, optional
        An end-to-end collision-probability budget Delta in (0, 0.5): plan
        a path whose certified bound on a collision at the step times
        (:func:`belief_nlp.risk.path_risk`, ``step_time``) is at most Delta,
        raising the planner's collision level in rounds until it is
        (:mod:`~belief_nlp.planner.budget`); the target containment keeps
        the scenario's chi2. None: ``scenario.risk`` when set, else the
        scenario's fixed level for everything (plan a scenario that has a
        budget at its fixed level with ``scenario.with_options(risk=None)``).
        IG-RRT* only.
    **options
        The other fields of :class:`~belief_nlp.planner.options.PlannerOptions`
        (``eig_range``, ``max_radius``, ``gamma``, ``goal_bias``,
        ``convergence_tol``, ``info_unit``, ``progress``, ...), or for OMPL
        those of :class:`~belief_nlp.planner.ompl_baseline.OMPLOptions`
        (``range``, ``goal_bias``, ``safety_margin``).

    Returns
    -------
    PlanResult
        ``success`` is True only for a path that passed
        :func:`belief_nlp.verify` (and, with a budget, whose certified bound
        is within it: ``risk`` records both); otherwise ``message`` says why.

    Raises
    ------
    ValidationError
        For an unknown option or an invalid value, naming it (an unknown
        ``planner``: field ``planner``; a budget outside (0, 0.5), not a
        number, or already spent by the start belief: field ``risk``; a
        start not clear at the scenario's level, held to a
        ``start_confidence``: field ``start.confidence``, since every edge
        is held to that level -- re-plan it with :func:`belief_nlp.replan`).
    ScenarioFileError
        When ``scenario`` names a file that cannot be read.
    SolverError
        When an OMPL planner is asked for and the ``ompl`` package is missing.
    """
    ompl_name = parse_planner(planner)
    if risk is not None:
        RiskBudget(risk)                          # a bad budget is refused before any file is read
    if isinstance(scenario, (str, os.PathLike)):
        scenario = load_scenario(scenario)
    if not isinstance(scenario, Scenario):
        raise ValidationError("scenario", f"must be a Scenario, a built-in name or a scenario file, "
                                          f"got {type(scenario).__name__}")
    if risk is not None:
        scenario = scenario.with_options(risk=risk)   # validated there: the start belief must leave some budget
    if scenario.start_confidence is not None and not np.min(scenario.start_clearances) >= scenario.chi2:
        # the planner holds every edge to the scenario's level: a start the relief was needed
        # for has no edge to grow from
        raise ValidationError("start.confidence", "the planner holds every edge to the scenario's level, and "
                                                  "this start is not clear at it: re-plan from a previous "
                                                  "path instead (belief_nlp.replan)")
    if ompl_name is not None:
        if scenario.risk is not None:
            raise ValidationError("risk", "applies to IG-RRT* only: OMPL planners plan at the scenario's fixed "
                                          "level (plan scenario.with_options(risk=None))")
        for name, value in (("n_nodes", n_nodes), ("branch_and_bound", branch_and_bound)):
            if value is not None:
                raise ValidationError(name, "applies to IG-RRT* only; OMPL planners are time-bounded "
                                            "(give time_limit)")
        return plan_ompl(scenario, ompl_name, seed=seed, alpha=alpha, metric=metric, noise=noise,
                         time_limit=time_limit, **options)
    if noise is not None:
        options["noise"] = noise
    if n_nodes is not None:
        options["n_nodes"] = n_nodes
    if branch_and_bound is not None:
        options["branch_and_bound"] = branch_and_bound
    if scenario.risk is not None:
        return plan_within_budget(scenario, seed=seed, alpha=alpha, metric=metric, time_limit=time_limit, **options)
    igrrt = IGRRTStar(scenario, seed=seed, alpha=alpha, metric=metric, time_limit=time_limit, **options)
    return igrrt.plan()
