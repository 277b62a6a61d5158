"""Validation of a :class:`~belief_nlp.scenario.Scenario`: every field's
checks in one place, run once by the constructor (docs/scenario_schema.md,
"Validation rules"). Every fault raises ValidationError naming the field."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from ._limits import MAX_ALPHA, MAX_CHI2, MAX_HORIZON, MAX_OBSTACLES, MAX_VARIANCE, MIN_NOISE_VARIANCE
from .errors import ValidationError
from .polytope import Polytope, _as_finite_array, _check_magnitude, _frozen


def _is_real(value: Any) -> bool:
    """A real number that is not a bool (TOML ``true`` must not pass as 1)."""
    return isinstance(value, (numbers.Real, np.floating, np.integer)) and not isinstance(value, (bool, np.bool_))


def _finite(value: Any) -> bool:
    """A real number with a finite float value (a 400-digit int is not: float() overflows)."""
    try:
        return _is_real(value) and math.isfinite(float(value))
    except OverflowError:
        return False


def _covariance(value: Any, d: int, field_name: str, allow_singular: bool) -> np.ndarray:
    """Parse a scalar / diagonal / full matrix and check symmetry and definiteness.

    A scalar ``s`` means ``s I``; a list of ``d`` numbers is the diagonal.
    """
    if _is_real(value):
        if not _finite(value):
            raise ValidationError(field_name, f"contains NaN or infinite values (got {value!r:.40})")
        arr = float(value) * np.eye(d)
    else:
        try:
            raw = np.asarray(value)
        except (TypeError, ValueError):
            raw = np.empty(0, dtype=object)
        if raw.dtype.kind not in "iuf" or raw.ndim > 2:
            raise ValidationError(field_name, f"must be a number (s * I), a list of {d} numbers (the diagonal) "
                                              f"or a {d}x{d} matrix, got {value!r}")
        arr = raw.astype(float)
        if arr.ndim == 0:
            arr = float(arr) * np.eye(d)
        elif arr.ndim == 1:
            if arr.size != d:
                raise ValidationError(field_name, f"diagonal must have {d} entries for a {d}-D scenario, got {arr.size}")
            arr = np.diag(arr)
    if arr.shape != (d, d):
        raise ValidationError(field_name, f"must be a {d}x{d} matrix for a {d}-D scenario, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(field_name, "contains NaN or infinite values")
    # |P_ij| <= lambda_max for a covariance: checking the entries first keeps
    # the eigenvalue computation away from overflow.
    scale = max(float(np.max(np.abs(arr))), 1e-300)
    if scale > MAX_VARIANCE:
        raise ValidationError(field_name, f"entries and eigenvalues must be at most {MAX_VARIANCE:g} m^2 "
                                          f"(a standard deviation of 1e6 m), got {scale:.3g}")
    if not np.allclose(arr, arr.T, rtol=0, atol=1e-12 * scale):
        raise ValidationError(field_name, "covariance is not symmetric")
    eig = np.linalg.eigvalsh(0.5 * (arr + arr.T))
    if allow_singular:
        if eig[0] < -1e-12 * scale:
            raise ValidationError(field_name, f"covariance is not positive semidefinite (eigenvalue {eig[0]:.3g})")
    elif eig[0] <= 1e-12 * scale:
        raise ValidationError(field_name, f"covariance is not positive definite (smallest eigenvalue {eig[0]:.3g})")
    elif eig[0] < MIN_NOISE_VARIANCE:
        raise ValidationError(field_name, f"smallest eigenvalue {eig[0]:.3g} is below the limit of "
                                          f"{MIN_NOISE_VARIANCE:g} m^2")
    if eig[-1] > MAX_VARIANCE:
        raise ValidationError(field_name, f"largest eigenvalue {eig[-1]:.3g} is above the limit of "
                                          f"{MAX_VARIANCE:g} m^2")
    return arr


def _validate(sc) -> None:
    """All checks of a :class:`~belief_nlp.scenario.Scenario` in one place
    (run by its constructor); raises ValidationError naming the field and
    stores the normalised values (read-only arrays, floats) on ``sc``."""
    for fname in ("name", "description"):
        if not isinstance(getattr(sc, fname), str):
            raise ValidationError(fname, f"must be a string, got {type(getattr(sc, fname)).__name__}")
    if not isinstance(sc.domain, Polytope) or not sc.domain.bounded:
        raise ValidationError("domain", "must be a bounded convex polytope")
    d = sc.domain.dim
    if d not in (2, 3):
        raise ValidationError("domain", f"only 2-D and 3-D scenarios are supported, got dimension {d}")
    if not isinstance(sc.target, Polytope) or not sc.target.bounded:
        raise ValidationError("target", "must be a bounded convex polytope")
    if sc.target.dim != d:
        raise ValidationError("target", f"is {sc.target.dim}-D but the domain is {d}-D")
    if isinstance(sc.obstacles, (str, bytes, dict, Polytope)) or not hasattr(sc.obstacles, "__iter__"):
        raise ValidationError("obstacles", f"must be a sequence of Polytope, got {type(sc.obstacles).__name__}")
    obstacles = tuple(sc.obstacles)
    if len(obstacles) > MAX_OBSTACLES:
        raise ValidationError("obstacles", f"{len(obstacles)} obstacles is more than the limit of {MAX_OBSTACLES}")
    for i, ob in enumerate(obstacles):
        if not isinstance(ob, Polytope):
            raise ValidationError(f"obstacles[{i}]", f"must be a Polytope, got {type(ob).__name__}")
        if ob.dim != d:
            raise ValidationError(f"obstacles[{i}]", f"is {ob.dim}-D but the domain is {d}-D")
        if not ob.bounded:
            raise ValidationError(f"obstacles[{i}]", "must be bounded")
    object.__setattr__(sc, "obstacles", tuple(
        ob if ob.name else Polytope(ob.A, ob.b, ob.vertices, f"obstacle {i + 1}", ob.spec)
        for i, ob in enumerate(obstacles)))

    x0 = _as_finite_array(sc.x0, "start.x", 1)
    if x0.size != d:
        raise ValidationError("start.x", f"must have {d} entries for a {d}-D scenario, got {x0.size}")
    _check_magnitude(x0, "start.x")
    # Private read-only copies: nobody can change a validated scenario in place.
    object.__setattr__(sc, "x0", _frozen(x0))
    object.__setattr__(sc, "P0", _frozen(_covariance(sc.P0, d, "start.P", allow_singular=True)))
    object.__setattr__(sc, "W", _frozen(_covariance(sc.W, d, "noise.W", allow_singular=False)))
    object.__setattr__(sc, "W_rate", _frozen(_covariance(sc.W_rate, d, "noise.W_rate", allow_singular=False)))

    if not _finite(sc.alpha) or not 0 <= float(sc.alpha) <= MAX_ALPHA:
        raise ValidationError("alpha", f"must be a finite number >= 0 and <= {MAX_ALPHA:g}, got {sc.alpha!r:.40}")
    object.__setattr__(sc, "alpha", float(sc.alpha))
    if sc.chi2_value is not None and sc.confidence is not None:
        raise ValidationError("chi2", "give either 'confidence' or 'chi2', not both")
    if sc.chi2_value is not None:
        if not _finite(sc.chi2_value) or not 0 < float(sc.chi2_value) <= MAX_CHI2:
            raise ValidationError("chi2", f"must be a finite number > 0 and <= {MAX_CHI2:g}, got {sc.chi2_value!r:.40}")
        object.__setattr__(sc, "chi2_value", float(sc.chi2_value))
    else:
        c = 0.9 if sc.confidence is None else sc.confidence
        if not _finite(c) or not 0 < float(c) < 1:
            raise ValidationError("confidence", f"must lie strictly between 0 and 1, got {c!r:.40}")
        object.__setattr__(sc, "confidence", float(c))
    if sc.K is not None:
        if not isinstance(sc.K, (int, np.integer)) or isinstance(sc.K, (bool, np.bool_)) or sc.K < 1:
            raise ValidationError("horizon.K", f"must be a positive integer, got {sc.K!r:.40}")
        if sc.K > MAX_HORIZON:
            raise ValidationError("horizon.K", f"{sc.K} is more than the limit of {MAX_HORIZON} steps")
        object.__setattr__(sc, "K", int(sc.K))
    if not isinstance(sc.planner, dict):
        raise ValidationError("planner", f"must be a table of planner options, got {type(sc.planner).__name__}")
    object.__setattr__(sc, "planner", dict(sc.planner))  # not shared with the caller

    # target inside the domain
    slack = sc.domain.b[None, :] - sc.target.vertices @ sc.domain.A.T
    if np.min(slack) < -1e-12:
        i, face = np.unravel_index(np.argmin(slack), slack.shape)
        raise ValidationError("target", f"target is not inside the domain (vertex {sc.target.vertices[i].tolist()} "
                                        f"is {-slack[i, face]:.3g} m outside domain face {face})")
    _validate_start_confidence(sc)
    # start ellipse inside the domain and clear of every obstacle, at its own level
    from .geometry import containment_margin, ellipse_clearance

    level = sc.chi2_start
    at = "" if sc.start_confidence is None else f" at start_confidence {sc.start_confidence:g}"
    hint = "" if sc.start_confidence is not None else (
        " (a re-plan from such an estimate: belief_nlp.relaxed_start, docs/mpc.md)")
    m = containment_margin(x0, sc.P0, sc.domain.A, sc.domain.b, level)
    if m < 0:
        raise ValidationError("start", f"start confidence ellipse{at} is not inside the domain (sticks out by "
                                       f"{-m:.3g} m){hint}")
    for ob in sc.obstacles:
        if ellipse_clearance(x0, sc.P0, ob.A, ob.b, level) < 0:
            raise ValidationError("start", f"start confidence ellipse{at} is not clear of {ob.name}{hint}")
    if sc.risk is not None:
        _validate_risk(sc)


def _validate_start_confidence(sc) -> None:
    """``start_confidence``: None, or a level in (0, 1) whose quantile is at
    most the scenario's chi2; not with a risk budget (which prices the start)."""
    c = sc.start_confidence
    if c is None:
        return
    if not _finite(c) or not 0 < float(c) < 1:
        raise ValidationError("start.confidence", f"must lie strictly between 0 and 1, got {c!r:.40}")
    object.__setattr__(sc, "start_confidence", float(c))
    if sc.risk is not None:
        raise ValidationError("start.confidence", "cannot be combined with a risk budget ('risk'): the budget "
                                                  "prices the start belief itself")
    from scipy.stats import chi2 as chi2_law

    if float(chi2_law.ppf(float(c), sc.dim)) > sc.chi2 * (1 + 1e-12):
        raise ValidationError("start.confidence", f"{float(c):g} is above the scenario's own level (chi2 = "
                                                  f"{sc.chi2:.5g}): the start may only be held to a lower one")


def _validate_risk(sc) -> None:
    """``risk``: a budget RiskBudget accepts, and more than the start belief
    alone spends. Every path's first transition starts at (x0, P0), so its
    certified clearance to hazard j is at most the start's squared
    Mahalanobis distance d_j, and its Boole sum at least sum_j g(d_j): a
    budget at or below that sum can be met by no path."""
    from .allocation import RiskBudget, tail

    budget = RiskBudget(sc.risk).budget
    object.__setattr__(sc, "risk", budget)
    d2 = sc.start_clearances
    spent = float(np.sum(tail(d2)))
    if not spent < budget:
        j = int(np.argmax(tail(d2)))
        raise ValidationError("risk", f"the budget {budget:.3g} is already spent by the start belief alone: its "
                                      f"collision bound is {spent:.3g} (most from {sc.hazards[j].name}); no path "
                                      f"can meet it")
