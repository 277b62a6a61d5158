"""Scenarios: domain, obstacles, target, start belief and noise, validated once.

File schema (TOML or JSON, the same tree in both)::

    name = "paper-multi"            # optional, string
    description = "..."             # optional, string
    confidence = 0.9                # or chi2 = 4.605 (not both); default 0.9
    alpha = 0.1                     # information weight (cost = control + alpha * info)

    [start]
    x = [0.15, 0.5]                 # mean, metres
    P = [[1e-9, 0.0], [0.0, 1e-9]]  # covariance, m^2; a scalar s means s*I,
                                    # a flat list of d numbers a diagonal
    [noise]
    W = 0.2e-3                      # process noise per time step (smoother), m^2
    W_rate = 1e-3                   # noise per metre travelled (planner), m^2/m

    [domain]                        # every polytope takes exactly one of:
    box = { lower = [0, 0], upper = [1, 1] }
    # vertices = [[x, y], ...]      #   2-D convex polygon, either orientation
    # A = [[...]], b = [...]        #   half-spaces A y <= b

    [target]
    box = { lower = [0.6, 0.0], upper = [0.7, 0.1] }

    [[obstacles]]                   # zero or more
    name = "obstacle 1"             # optional
    vertices = [[0.145, 0.40], [0.105, 0.34], [0.225, 0.30], [0.225, 0.36]]

    [horizon]                       # optional default for the smoother
    K = 20

    [planner]                       # optional defaults passed to the planner
    max_radius = 0.3

All lengths in metres. ``chi2`` is the ``confidence`` quantile of the chi-square
law with ``d`` degrees of freedom unless given directly. The full schema, units
and validation rules are in ``docs/scenario_schema.md``.

Limits (``belief_nlp._limits``): files up to 8 MiB and 32 levels of nesting;
coordinates within +-1e6 m; eigenvalues of ``start.P``, ``noise.W`` and
``noise.W_rate`` at most 1e12 m^2, and those of the noise at least 1e-20 m^2;
``alpha`` <= 1e6; ``chi2`` <= 1e4; ``horizon.K`` <= 10000; at most 1000
obstacles of at most 20000 vertices (10000 half-spaces) each.
"""

from __future__ import annotations

import json
import math
import numbers
import os
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ._limits import (MAX_ALPHA, MAX_CHI2, MAX_HORIZON, MAX_NAME_LENGTH, MAX_OBSTACLES, MAX_SCENARIO_FILE_BYTES,
                      MAX_VARIANCE, MIN_NOISE_VARIANCE, check_document, parse_document, read_file)
from .errors import ScenarioFileError, ValidationError
from .path import _values_equal
from .polytope import Polytope, _as_finite_array, _check_magnitude, _frozen

__all__ = ["Scenario", "load_scenario", "save_scenario", "list_scenarios", "scenario_from_dict"]

_BUILTIN_PACKAGE = "belief_nlp.scenarios"


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


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated planning problem.

    Build with :func:`scenario_from_dict`, :func:`load_scenario` or the
    constructor (which validates too); :meth:`with_options` gives a copy
    with some fields changed. The file form is described in
    docs/scenario_schema.md.

    Parameters
    ----------
    domain : Polytope
        The bounded region the robot stays in (its outside is the walls).
    target : Polytope
        Where the final confidence ellipse must lie.
    obstacles : tuple of Polytope
        Convex obstacles the confidence ellipses must avoid.
    x0 : array_like, shape (d,)
        Start mean.
    P0 : array_like, shape (d, d)
        Start covariance (positive semidefinite).
    W : array_like, shape (d, d)
        Process noise per time step (the smoother's model, paper eq. 2).
    W_rate : array_like, shape (d, d)
        Process noise per metre travelled (the authors' planner).
    alpha : float, optional
        Information weight (>= 0), default 0.1.
    confidence : float or None, optional
        Confidence level of the ellipses, in (0, 1); 0.9 when neither it nor
        ``chi2_value`` is given. :attr:`chi2` is the matching chi-square
        quantile for :attr:`dim` degrees of freedom.
    chi2_value : float or None, optional
        The squared radius given directly instead of ``confidence`` (not
        both); ``confidence`` is then None.
    K : int or None, optional
        Default horizon of the smoother.
    planner : dict, optional
        Default keyword options for the planner (its ``[planner]`` table).
    name : str, optional
        Name of the scenario (built-ins: ``"paper-multi"``, ...).
    description : str, optional
        One line for listings.

    Raises
    ------
    ValidationError
        For any bad value; the error names the field (``"start.P"``,
        ``"obstacles[2].vertices"``, ...).
    """

    domain: Polytope
    target: Polytope
    obstacles: tuple[Polytope, ...]
    x0: np.ndarray
    P0: np.ndarray
    W: np.ndarray
    W_rate: np.ndarray
    alpha: float = 0.1
    confidence: float | None = None
    chi2_value: float | None = None
    K: int | None = None
    planner: dict = field(default_factory=dict)
    name: str = ""
    description: str = ""

    def __post_init__(self) -> None:
        _validate(self)

    # ------------------------------------------------------------------ basics
    @property
    def dim(self) -> int:
        """Dimension d of the space (2 or 3)."""
        return self.domain.dim

    @cached_property
    def chi2(self) -> float:
        """Squared radius of the confidence ellipses {y : (y-x)^T P^-1 (y-x) <= chi2}."""
        if self.chi2_value is not None:
            return float(self.chi2_value)
        from scipy.stats import chi2 as chi2_law

        return float(chi2_law.ppf(self.confidence, self.dim))

    @cached_property
    def walls(self) -> tuple[Polytope, ...]:
        """The outside of the domain as half-space obstacles (paper's X_out^l)."""
        return tuple(self.domain.complement_halfspaces("wall"))

    @cached_property
    def hazards(self) -> tuple[Polytope, ...]:
        """Everything a confidence ellipse must avoid: obstacles, then walls (J = M + L)."""
        return tuple(self.obstacles) + self.walls

    def with_options(self, **changes: Any) -> "Scenario":
        """A copy with some fields replaced (validated again).

        The keywords are the constructor's fields (``x0``, ``P0``, ``W``,
        ``chi2_value``, ``K``, ...); any other raises ValidationError naming it.
        """
        unknown = sorted(set(changes) - set(self.__dataclass_fields__))
        if unknown:
            raise ValidationError(unknown[0], f"unknown scenario field; known: {', '.join(self.__dataclass_fields__)}")
        data = {f: getattr(self, f) for f in self.__dataclass_fields__}
        # Choosing one of confidence / chi2_value drops the other.
        if "chi2_value" in changes and "confidence" not in changes:
            data["confidence"] = None
        if "confidence" in changes and "chi2_value" not in changes:
            data["chi2_value"] = None
        data.update(changes)
        return Scenario(**data)

    # ------------------------------------------------------------- serialise
    def to_dict(self) -> dict:
        """The scenario in the file schema; :func:`scenario_from_dict` reads it back equal.

        Returns
        -------
        dict
            The tables of docs/scenario_schema.md (``domain``, ``obstacles``,
            ``target``, ``start``, ``noise``, ...), as :func:`save_scenario` writes them.
        """
        out: dict[str, Any] = {}
        if self.name:
            out["name"] = self.name
        if self.description:
            out["description"] = self.description
        if self.chi2_value is not None:
            out["chi2"] = float(self.chi2_value)
        else:
            out["confidence"] = float(self.confidence)
        out["alpha"] = float(self.alpha)
        out["start"] = {"x": self.x0.tolist(), "P": self.P0.tolist()}
        out["noise"] = {"W": self.W.tolist(), "W_rate": self.W_rate.tolist()}
        out["domain"] = self.domain.to_dict()
        out["target"] = self.target.to_dict()
        out["obstacles"] = [o.to_dict() for o in self.obstacles]
        if self.K is not None:
            out["horizon"] = {"K": int(self.K)}
        if self.planner:
            out["planner"] = dict(self.planner)
        return out

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scenario):
            return NotImplemented
        # NaN-aware: the free-form planner table may hold a NaN (checked only when planning)
        return _values_equal(self.to_dict(), other.to_dict())

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (f"Scenario({self.name!r}, dim={self.dim}, obstacles={len(self.obstacles)}, "
                f"chi2={self.chi2:.4g}, alpha={self.alpha:g})")


# ---------------------------------------------------------------- validation
def _validate(sc: Scenario) -> None:
    """All checks in one place; raises ValidationError naming the field."""
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
    # start ellipse inside the domain and clear of every obstacle
    from .geometry import containment_margin, ellipse_clearance

    m = containment_margin(x0, sc.P0, sc.domain.A, sc.domain.b, sc.chi2)
    if m < 0:
        raise ValidationError("start", f"start confidence ellipse is not inside the domain (sticks out by {-m:.3g} m)")
    for ob in sc.obstacles:
        if ellipse_clearance(x0, sc.P0, ob.A, ob.b, sc.chi2) < 0:
            raise ValidationError("start", f"start confidence ellipse is not clear of {ob.name}")


# -------------------------------------------------------------------- files
_TOP_KEYS = ("name", "description", "confidence", "chi2", "alpha", "start", "noise", "domain", "target",
             "obstacles", "horizon", "planner")
_TABLE_KEYS = {"start": (("x", "P"), ()), "noise": (("W",), ("W_rate",)), "horizon": ((), ("K",))}


def scenario_from_dict(data: Any, source: str = "scenario") -> Scenario:
    """Build a :class:`Scenario` from the file schema (docs/scenario_schema.md).

    Parameters
    ----------
    data : dict
        The scenario's tables, as read from a TOML or JSON file
        (:meth:`Scenario.to_dict` writes them).
    source : str, optional
        What the data came from (a file name), quoted in error messages.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ScenarioFileError
        For structural faults: not a table, missing or unknown keys, wrong types.
    ValidationError
        For bad values. Both name the field.
    """
    if not isinstance(data, dict):
        raise ScenarioFileError("file", f"{source}: the top level must be a table/object, got {type(data).__name__}")
    check_document(data, source)  # nesting depth and integer sizes of dicts built in memory too
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise ScenarioFileError(unknown[0], f"unknown key in {source} (known keys: {', '.join(_TOP_KEYS)})")
    for key in ("start", "noise", "domain", "target"):
        if key not in data:
            raise ScenarioFileError(key, f"required key is missing in {source}")
    if "confidence" in data and "chi2" in data:
        raise ScenarioFileError("chi2", "give either 'confidence' or 'chi2', not both")
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            raise ScenarioFileError(key, f"must be a string, got {type(data[key]).__name__}")
    for key in ("alpha", "confidence", "chi2"):
        if key in data and not _is_real(data[key]):
            raise ScenarioFileError(key, f"must be a number, got {type(data[key]).__name__}: {data[key]!r}")

    tables: dict[str, dict] = {}
    for key, (required, optional) in _TABLE_KEYS.items():
        t = data.get(key, {})
        if not isinstance(t, dict):
            raise ScenarioFileError(key, f"must be a table/object, got {type(t).__name__}")
        extra = sorted(set(t) - set(required) - set(optional))
        if extra:
            raise ScenarioFileError(f"{key}.{extra[0]}", f"unknown key (allowed: {', '.join(required + optional)})")
        for r in required:
            if r not in t:
                raise ScenarioFileError(f"{key}.{r}", "required key is missing")
        tables[key] = t
    obstacles = data.get("obstacles", [])
    if not isinstance(obstacles, list):
        raise ScenarioFileError("obstacles", f"must be an array of tables, got {type(obstacles).__name__}")
    if len(obstacles) > MAX_OBSTACLES:  # before building any of them
        raise ValidationError("obstacles", f"{len(obstacles)} obstacles is more than the limit of {MAX_OBSTACLES}")
    planner = data.get("planner", {})
    if not isinstance(planner, dict):
        raise ScenarioFileError("planner", f"must be a table of planner options, got {type(planner).__name__}")
    K = tables["horizon"].get("K")
    if K is not None and (not isinstance(K, int) or isinstance(K, bool)):
        raise ScenarioFileError("horizon.K", f"must be an integer, got {type(K).__name__}: {K!r}")

    # Geometry first, so that a dimension mismatch is reported as such and not
    # as a wrongly sized covariance.
    domain = Polytope.from_dict(data["domain"], "domain")
    target = Polytope.from_dict(data["target"], "target")
    obs = tuple(Polytope.from_dict(o, f"obstacles[{i}]") for i, o in enumerate(obstacles))
    d = domain.dim
    if target.dim != d:
        raise ValidationError("target", f"is {target.dim}-D but the domain is {d}-D")
    for i, o in enumerate(obs):
        if o.dim != d:
            raise ValidationError(f"obstacles[{i}]", f"is {o.dim}-D but the domain is {d}-D")
    start, noise = tables["start"], tables["noise"]
    return Scenario(
        domain=domain,
        target=target,
        obstacles=obs,
        x0=_as_finite_array(start["x"], "start.x", 1),
        P0=_covariance(start["P"], d, "start.P", allow_singular=True),
        W=_covariance(noise["W"], d, "noise.W", allow_singular=False),
        W_rate=_covariance(noise.get("W_rate", noise["W"]), d, "noise.W_rate", allow_singular=False),
        alpha=data.get("alpha", 0.1),
        confidence=data.get("confidence"),
        chi2_value=data.get("chi2"),
        K=K,
        planner=dict(planner),
        name=data.get("name", ""),
        description=data.get("description", ""),
    )


def list_scenarios() -> list[str]:
    """Names of the built-in scenarios.

    Returns
    -------
    list of str
        Sorted names that :func:`load_scenario` takes (``"cube3d"``,
        ``"paper-multi"``, ``"quad"``, ``"tutorial"``, ...).
    """
    files = resources.files(_BUILTIN_PACKAGE).iterdir()
    return sorted(p.name[:-5] for p in files if p.name.endswith(".toml"))


def load_scenario(name_or_path: str | os.PathLike | Scenario) -> Scenario:
    """Load a built-in scenario by name, or a ``.toml`` / ``.json`` file.

    Parameters
    ----------
    name_or_path : str, os.PathLike or Scenario
        A built-in name (:func:`list_scenarios`), a scenario file (files
        whose suffix is neither ``.toml`` nor ``.json`` are read as TOML), or
        a Scenario, returned as it is.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ScenarioFileError
        Field ``"file"`` for an unreadable, malformed, too large (> 8 MiB) or
        too deeply nested (> 32 levels) file; ``"name"`` for an unknown
        built-in or a name longer than 4096 characters; schema faults name
        their key.
    ValidationError
        Field ``"scenario"`` for a value other than a name, a path or a
        Scenario; bad values in a file name their field.
    """
    if isinstance(name_or_path, Scenario):
        return name_or_path
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ValidationError("scenario", f"must be a built-in name, a scenario file or a Scenario, "
                                          f"got {type(name_or_path).__name__}")
    text_name = os.fsdecode(name_or_path)
    if len(text_name) > MAX_NAME_LENGTH:
        raise ScenarioFileError("name", f"a scenario name or file name of {len(text_name)} characters is longer "
                                        f"than the limit of {MAX_NAME_LENGTH}")
    path = Path(text_name)
    try:
        is_file = path.suffix.lower() in (".toml", ".json") or path.exists()
    except (OSError, ValueError):  # a name the OS refuses (too long a component, NUL): not a file
        is_file = False
    if is_file:
        raw = read_file(path, "file", MAX_SCENARIO_FILE_BYTES, "scenario file")
        fmt = "json" if path.suffix.lower() == ".json" else "toml"
        return _parse(raw, fmt, text_name)
    if text_name in list_scenarios():
        raw = resources.files(_BUILTIN_PACKAGE).joinpath(f"{text_name}.toml").read_bytes()
        return _parse(raw, "toml", text_name)
    shown = text_name if len(text_name) <= 80 else text_name[:80] + "..."
    raise ScenarioFileError("name", f"unknown scenario {shown!r}; built-ins: {', '.join(list_scenarios())}")


def _parse(raw: bytes, fmt: str, source: str) -> Scenario:
    return scenario_from_dict(parse_document(raw, fmt, source, "file"), source)


def save_scenario(scenario: Scenario, path: str | os.PathLike) -> Path:
    """Write ``scenario`` as TOML or JSON; :func:`load_scenario` reads it back equal.

    Parameters
    ----------
    scenario : Scenario
        The scenario to write.
    path : str or os.PathLike
        The file; its suffix (``.toml`` or ``.json``) chooses the format.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        When ``scenario`` is not a Scenario or ``path`` has another suffix.
    ScenarioFileError
        Naming ``file`` when the file cannot be written (missing folder, no
        permission).
    """
    if not isinstance(scenario, Scenario):
        raise ValidationError("scenario", f"must be a Scenario, got {type(scenario).__name__}")
    if not isinstance(path, (str, os.PathLike)):
        raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
    path = Path(path)
    data = scenario.to_dict()
    try:
        if path.suffix.lower() == ".json":
            text = json.dumps(data, indent=2, allow_nan=False)
        elif path.suffix.lower() == ".toml":
            import tomli_w

            text = tomli_w.dumps(data)
        else:
            raise ValidationError("path", f"scenario files end in .toml or .json, got {path.suffix!r}")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ValidationError):
            raise
        raise ValidationError("planner", f"cannot be written to {path.suffix}: {exc}") from exc
    try:
        path.write_text(text)
    except (OSError, ValueError) as exc:
        raise ScenarioFileError("file", f"cannot write {str(path)[:200]}: {exc}") from exc
    return path
