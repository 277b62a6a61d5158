"""Resuming an NLP method from an earlier answer's first-stage state.

A re-plan from a new start belief solves the same NLP graph as the earlier
call with another parameter value (the start belief is a parameter,
:mod:`belief_nlp.model.nlp_form`). The earlier answer's first-stage variables
and multipliers are then a start that IPOPT converges from in a few
iterations (``warm_start_init_point``, pushed no further into the interior
than 1e-9: the backend's ``resume_options``): 4-8 iterations instead of
35-118 from the re-anchored path alone on paper-multi at K = 20
(docs/numerics.md, "The start belief as a parameter, and re-planning"). The engine keeps that state on the
result (:attr:`belief_nlp.SmoothResult.resume`, in memory only) and
:func:`belief_nlp.replan` passes it back as the method option ``resume``.

After executed steps (``replan(..., advance=k)``) the horizon is k steps
shorter: the state then says so (``offset``, :func:`advanced`) and the
engine solves the re-plan on the state's own, longer graph with its first
``offset`` steps frozen at the new start (:mod:`belief_nlp.model.nlp_prefix`):
nothing is built and the multipliers fit.

When the answer was the exact polish's (the second stage on the "cholesky"
NLP), the state also holds that polish's variables and multipliers
(``polish``); the engine then resumes the polish alone, its switched-off
sensing kept off, and the first stage only when that does not converge
(session 15: K = 40 loop re-plans 0.26 s instead of 0.46 s with IPOPT).

A solver that takes no initial multipliers (fatrop, Uno) keeps a state
without them (``lam_x`` and ``lam_g`` None): nothing to resume from, but a
re-plan after executed steps is still solved on the state's graph with its
steps frozen, from the warm start, so it builds nothing (session 29).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["state", "matches", "check", "advanced", "has_duals"]

_KEYS = {"plugin", "key", "floor", "offset", "z", "lam_x", "lam_g", "polish", "polish_skip", "stage_skip"}


def state(plugin: str, key: str, floor: float, z: np.ndarray, duals: tuple | None, offset: int = 0,
          polish: tuple | None = None, polish_skip: int = 0, stage_skip: int = 0) -> dict:
    """The resumable state of a converged first stage: the graph's key (the
    scenario and K without the start belief and alpha), the floor, the
    steps of that graph frozen before the answer's (``offset``), the
    variables and the multipliers (lam_x, lam_g; None for a solver that
    takes none: the state then serves the graph only); ``polish`` (z, (lam_x,
    lam_g)): the polish's answer when it is the run's; ``polish_skip``: how
    many more re-plans skip the polish (it did not lower a recent answer);
    ``stage_skip``: how many more re-plans a composite method runs without
    this NLP stage (``auto``, after an answer CCP gave because IPOPT's was
    not taken; the NLP methods themselves ignore it)."""
    return {"plugin": plugin, "key": key, "floor": float(floor), "offset": int(offset), **_arrays(z, duals),
            "polish": _arrays(*polish) if polish else None, "polish_skip": int(polish_skip),
            "stage_skip": int(stage_skip)}


def _arrays(z: np.ndarray, duals: tuple | None) -> dict:
    """A stage's variables and multipliers (None: none), as a state holds them."""
    lam = (None, None) if duals is None else (np.array(duals[0], float), np.array(duals[1], float))
    return {"z": np.array(z, float), "lam_x": lam[0], "lam_g": lam[1]}


def has_duals(resume: dict) -> bool:
    """Whether ``resume`` holds multipliers to start a solver from."""
    return resume["lam_x"] is not None


def advanced(resume: dict | None, advance: int) -> dict | None:
    """``resume`` after ``advance`` executed steps: the same graph with that
    many more steps frozen (None stays None)."""
    if resume is None or not advance:
        return resume
    return {**resume, "offset": int(resume["offset"]) + int(advance)}


def matches(resume: dict, plugin: str, key: str, floor: float) -> bool:
    """Whether ``resume`` was taken on the same graph, plug-in and floor (its
    arrays then have this NLP's sizes)."""
    return resume["plugin"] == plugin and resume["key"] == key and resume["floor"] == float(floor)


def check(v: Any) -> str | None:
    """The ``resume`` option's check: None or a state of :func:`state`."""
    if v is None:
        return None
    def array(a: Any) -> bool:
        return isinstance(a, np.ndarray) and a.ndim == 1 and bool(np.all(np.isfinite(a)))

    def arrays(d: Any, bare: bool = False) -> bool:
        # multipliers both given, or (``bare``) both None: a solver that takes none
        return isinstance(d, dict) and array(d.get("z")) and "lam_x" in d and "lam_g" in d and (
            all(array(d[k]) for k in ("lam_x", "lam_g")) or (bare and d["lam_x"] is None and d["lam_g"] is None))

    arrays_ok = isinstance(v, dict) and set(v) == _KEYS and arrays(v, bare=True) \
        and (v["polish"] is None or (v["lam_x"] is not None and arrays(v["polish"])))
    counts_ok = arrays_ok and all(isinstance(v[k], int) and not isinstance(v[k], bool) and v[k] >= 0
                                  for k in ("offset", "polish_skip", "stage_skip"))
    if not counts_ok:
        return "must be None or a SmoothResult's resume state (SmoothResult.resume)"
    return None
