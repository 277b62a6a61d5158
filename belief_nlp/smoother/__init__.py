"""The shared smoothing driver: method registry, problem context, warm start and results."""

from .context import Check, Outcome, SmoothingProblem
from .driver import smooth
from .registry import (DEFAULT_METHOD, Method, Option, available_methods, available_solvers, get_method, register,
                       unregister)
from .replan import reanchor, relaxed_start, replan
from .result import STATUSES, IterationRecord, SmoothResult
from .warmstart import WarmStart, warm_start

__all__ = ["Check", "DEFAULT_METHOD", "IterationRecord", "Method", "Option", "Outcome", "STATUSES",
           "SmoothResult", "SmoothingProblem", "WarmStart", "available_methods", "available_solvers", "get_method",
           "reanchor", "register", "relaxed_start", "replan", "smooth", "unregister", "warm_start"]
