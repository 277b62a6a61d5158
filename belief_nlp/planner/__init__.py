"""IG-RRT*: sampling-based planning in Gaussian belief space.

``plan(scenario, n_nodes=..., seed=...)`` returns a :class:`PlanResult` whose
path has been checked by :func:`belief_nlp.verify`. See :mod:`.rrt` for the
algorithm and :mod:`.metrics` for the edge cost and its units;
``plan(scenario, planner="ompl:RRTstar")`` runs the OMPL baseline instead
(:mod:`.ompl_baseline`).
"""

from __future__ import annotations

from .options import PlannerOptions
from .result import PlanResult, TreeView
from .api import plan
from .ompl_baseline import DEFAULT_PLANNER, ompl_planners
from .rrt import IGRRTStar

__all__ = ["DEFAULT_PLANNER", "IGRRTStar", "PlanResult", "PlannerOptions", "TreeView", "ompl_planners", "plan"]
