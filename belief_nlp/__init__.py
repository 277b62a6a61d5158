"""belief_nlp: minimum-sensing path planning in Gaussian belief space.

Plan with IG-RRT*, smooth with any registered method (the convex-concave
procedure, IPOPT, or yours) on one symbolic model, and verify every path
independently. See README.md for a tour and docs/architecture.md for the map.
"""

from __future__ import annotations

from . import belief, geometry
from ._version import __version__
from .errors import (BeliefNLPError, InfeasibleStartError, ScenarioFileError, SolverError,
                     ValidationError)
from .path import BeliefPath
from .polytope import Polytope
from .scenario import Scenario, list_scenarios, load_scenario, save_scenario, scenario_from_dict
from .allocation import RiskAllocation, RiskBudget
from .verify import VerificationReport, verify
from .smoother import (DEFAULT_METHOD, STATUSES, IterationRecord, Method, Option, Outcome, SmoothResult,
                       SmoothingProblem, WarmStart, available_methods, available_solvers, get_method, reanchor,
                       relaxed_start, replan, smooth, warm_start)
from .smoother import register as register_method
from . import methods  # noqa: F401 - importing registers the built-in methods
from .methods.ccp_subproblem import ccp_subproblem, ccp_subproblem_path
from .planner import IGRRTStar, PlanResult, plan
from .comparison import compare, records_to_table
from .study.records import load_records
from .study.ompl_export import export_ompl_benchmark
from .model.cache import set_disk_cache

# Heavier or optional modules load on first use (plotting pulls in pyplot).
_LAZY = {"plotting", "export"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'belief_nlp' has no attribute {name!r}")


__all__ = [
    "RiskAllocation",
    "RiskBudget",
    "BeliefNLPError",
    "DEFAULT_METHOD",
    "Method",
    "Option",
    "Outcome",
    "STATUSES",
    "SmoothingProblem",
    "available_methods",
    "available_solvers",
    "ccp_subproblem",
    "ccp_subproblem_path",
    "get_method",
    "register_method",
    "BeliefPath",
    "IGRRTStar",
    "InfeasibleStartError",
    "IterationRecord",
    "PlanResult",
    "Polytope",
    "Scenario",
    "ScenarioFileError",
    "SmoothResult",
    "SolverError",
    "ValidationError",
    "VerificationReport",
    "belief",
    "compare",
    "export_ompl_benchmark",
    "geometry",
    "list_scenarios",
    "load_records",
    "load_scenario",
    "plan",
    "reanchor",
    "records_to_table",
    "relaxed_start",
    "replan",
    "save_scenario",
    "scenario_from_dict",
    "set_disk_cache",
    "smooth",
    "verify",
    "warm_start",
    "WarmStart",
]
