"""Coercion of the public API's common inputs, shared by the smoother's driver,
the methods and :func:`belief_nlp.compare` (a home below all of them, so that
methods depend on the smoother's interface and never the other way round)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .errors import ValidationError
from .path import BeliefPath, result_path
from .scenario import Scenario, load_scenario

__all__ = ["as_scenario", "as_path", "load_path_file"]


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
    either of them, from a result with a ``.path`` (PlanResult, SmoothResult),
    or from a file holding one (str or path: a plan result, belief path or
    smoothing result, JSON or NPZ -- what ``belief-nlp smooth --path`` reads).

    Raises
    ------
    ValidationError
        ``path`` is none of these (a bad file: field ``path``).
    """
    from .smoother.warmstart import WarmStart

    if isinstance(path, (BeliefPath, WarmStart)):
        return path
    if isinstance(path, (str, os.PathLike)):
        return load_path_file(path, "path")[0]
    inner = result_path(path)                 # PlanResult, SmoothResult
    if inner is not None:
        return inner
    raise ValidationError("path", f"must be a BeliefPath, a WarmStart or a result with a .path, "
                                  f"got {type(path).__name__}")


def load_path_file(file: str | os.PathLike, field: str = "path") -> tuple[BeliefPath, dict]:
    """A BeliefPath from a plan result, a belief path or a smoothing result
    file (JSON or NPZ), and a dict saying what the file held. Every fault
    (missing, malformed, too deep, no path inside) raises our own error
    naming ``field``."""
    import numpy as np

    from ._limits import load_json

    file = Path(file)
    if not file.is_file():
        raise ValidationError(field, f"no such file: {file}")
    if file.suffix == ".npz":
        try:
            with np.load(file, allow_pickle=False) as z:
                names = set(z.files)
        except (OSError, ValueError) as exc:
            raise ValidationError(field, f"{file}: not an NPZ file: {exc}") from None
        if "header" in names:
            return _path_of_plan(_plan_result_cls().load(file), file, field)
        if "smooth_header" in names:
            from .smoother.result import SmoothResult

            return SmoothResult.load(file).path, {"source": str(file), "kind": "smooth result"}
        return BeliefPath.load(file), {"source": str(file), "kind": "path"}
    data = load_json(file, field)          # size, nesting and syntax limits: our own error, one line
    if isinstance(data, dict) and str(data.get("format", "")).startswith("belief_nlp.PlanResult"):
        return _path_of_plan(_plan_result_cls().from_dict(data), file, field)
    if isinstance(data, dict) and "path" in data and "x" not in data:
        if not isinstance(data["path"], dict):
            raise ValidationError(field, f"{file}: the result holds no path")
        return BeliefPath.from_dict(data["path"]), {"source": str(file), "kind": "smooth result"}
    return BeliefPath.from_dict(data), {"source": str(file), "kind": "path"}


def _plan_result_cls():
    from .planner import PlanResult

    return PlanResult


def _path_of_plan(result, file: Path, field: str):
    if result.path is None:
        raise ValidationError(field, f"{file}: the plan result holds no path ({result.message})")
    return result.path, {"source": str(file), "kind": "plan result", "scenario": result.scenario}
