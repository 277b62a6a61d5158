"""Resuming an NLP method from an earlier answer's first-stage state.

A re-plan from a new start belief solves the same NLP graph as the earlier
call with another parameter value (the start belief is a parameter,
:mod:`belief_nlp.model.nlp_form`). The earlier answer's first-stage variables
and multipliers are then a start that IPOPT converges from in a few
iterations (``warm_start_init_point``, the barrier started small: the
backend's ``resume_options``): 4-8 iterations instead of 35-118 from the
re-anchored path alone on paper-multi at K = 20 (docs/numerics.md, "The start
belief as a parameter, and re-planning"). The engine keeps that state on the
result (:attr:`belief_nlp.SmoothResult.resume`, in memory only) and
:func:`belief_nlp.replan` passes it back as the method option ``resume``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["state", "matches", "check"]

_KEYS = {"plugin", "key", "floor", "z", "lam_x", "lam_g"}


def state(plugin: str, key: str, floor: float, z: np.ndarray, duals: tuple) -> dict:
    """The resumable state of a converged first stage: the graph's key (the
    scenario and K without the start belief and alpha), the floor, the
    variables and the multipliers (lam_x, lam_g)."""
    return {"plugin": plugin, "key": key, "floor": float(floor), "z": np.array(z, float),
            "lam_x": np.array(duals[0], float), "lam_g": np.array(duals[1], float)}


def matches(resume: dict, plugin: str, key: str, floor: float) -> bool:
    """Whether ``resume`` was taken on the same graph, plug-in and floor (its
    arrays then have this NLP's sizes)."""
    return resume["plugin"] == plugin and resume["key"] == key and resume["floor"] == float(floor)


def check(v: Any) -> str | None:
    """The ``resume`` option's check: None or a state of :func:`state`."""
    if v is None:
        return None
    if not isinstance(v, dict) or set(v) != _KEYS or not all(
            isinstance(v[k], np.ndarray) and v[k].ndim == 1 and np.all(np.isfinite(v[k])) for k in ("z", "lam_x",
                                                                                                    "lam_g")):
        return "must be None or a SmoothResult's resume state (SmoothResult.resume)"
    return None
