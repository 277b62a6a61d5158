"""Coercion of the public API's common inputs, shared by the smoother's driver,
the methods and :func:`belief_nlp.compare` (a home below all of them, so that
methods depend on the smoother's interface and never the other way round)."""

from __future__ import annotations

from typing import Any

from .errors import ValidationError
from .path import BeliefPath
from .scenario import Scenario, load_scenario

__all__ = ["as_scenario", "as_path"]


def as_scenario(scenario: Any) -> Scenario:
    """A :class:`Scenario` from a Scenario, a built-in name or a scenario file.

    Raises
    ------
    ValidationError
        ``scenario`` is of another type.
    """
    if isinstance(scenario, str):
        return load_scenario(scenario)
    if not isinstance(scenario, Scenario):
        raise ValidationError("scenario", f"must be a Scenario or a scenario name/file, got {type(scenario).__name__}")
    return scenario


def as_path(path: Any):
    """A :class:`BeliefPath` or :class:`~belief_nlp.smoother.WarmStart` from
    either of them or from a result with a ``.path`` (PlanResult, SmoothResult).

    Raises
    ------
    ValidationError
        ``path`` is none of these.
    """
    from .smoother.warmstart import WarmStart

    if isinstance(path, (BeliefPath, WarmStart)):
        return path
    inner = getattr(path, "path", None)       # PlanResult, SmoothResult
    if isinstance(inner, BeliefPath):
        return inner
    raise ValidationError("path", f"must be a BeliefPath, a WarmStart or a result with a .path, "
                                  f"got {type(path).__name__}")
