"""IG-RRT*: sampling-based planning in Gaussian belief space.

``plan(scenario, n_nodes=..., seed=...)`` returns a :class:`PlanResult` whose
path has been checked by :func:`belief_nlp.verify`. See :mod:`.rrt` for the
algorithm and :mod:`.metrics` for the edge cost and its units.
"""

from __future__ import annotations

from .options import PlannerOptions
from .result import PlanResult, TreeView
from .rrt import IGRRTStar, plan

__all__ = ["IGRRTStar", "PlanResult", "PlannerOptions", "TreeView", "plan"]
