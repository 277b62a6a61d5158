"""Scenarios: domain, obstacles, target, start belief and noise, validated once.

File schema (TOML or JSON, the same tree in both)::

    name = "paper-multi"            # optional, string
    description = "..."             # optional, string
    confidence = 0.9                # or chi2 = 4.605 (not both); default 0.9
    # risk = 0.05                   # optional end-to-end collision budget: then
                                    # confidence / chi2 is the target's level only
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
import os
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ._limits import MAX_NAME_LENGTH, MAX_OBSTACLES, MAX_SCENARIO_FILE_BYTES, check_document, parse_document, read_file
from .errors import ScenarioFileError, ValidationError
from .path import _values_equal
from .polytope import Polytope, _as_finite_array
from .scenario_validate import _covariance, _is_real, _validate

__all__ = ["Scenario", "load_scenario", "save_scenario", "list_scenarios", "scenario_from_dict"]

_BUILTIN_PACKAGE = "belief_nlp.scenarios"


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
    risk : float or None, optional
        An end-to-end collision-probability budget Delta in (0, 0.5) (the
        file's ``risk`` key; :class:`~belief_nlp.allocation.RiskBudget`),
        instead of one fixed level for the collisions:
        :func:`belief_nlp.plan` then plans within it (``plan(..., risk=)``)
        and ``confidence`` / ``chi2`` is the target containment level
        (default 0.9). None (default): the fixed level for everything. A
        budget that the start belief alone spends is refused.
    start_confidence : float or None, optional
        The level the start belief and the first transition are held to,
        at most ``confidence`` (the file's ``start.confidence``). For a
        re-plan from an estimate whose ellipse already touches a hazard at
        ``confidence``: no plan can clear a start, so transition 1 is
        certified at this level and every later one at ``confidence``
        (:func:`belief_nlp.relaxed_start` picks it; docs/mpc.md). None
        (default): ``confidence``. Not with a risk budget, which prices the
        start itself.

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
    risk: float | None = None
    start_confidence: float | None = None

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
    def chi2_start(self) -> float:
        """The level of the start belief and of transition 1: the ``start_confidence``
        quantile, or :attr:`chi2` when it is None."""
        if self.start_confidence is None:
            return self.chi2
        from scipy.stats import chi2 as chi2_law

        return min(float(chi2_law.ppf(self.start_confidence, self.dim)), self.chi2)

    @cached_property
    def start_clearances(self) -> np.ndarray:
        """(J,) squared Mahalanobis distance of the start belief to every
        hazard (:attr:`hazards` order): what no path's first transition can exceed."""
        from .geometry import PolytopeSet, squared_mahalanobis_distance

        return squared_mahalanobis_distance(self.x0[None], self.P0[None], PolytopeSet.cached(self.hazards))[0]

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
        ``chi2_value``, ``K``, ``risk``, ...); any other raises
        ValidationError naming it.
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
        if self.risk is not None:
            out["risk"] = float(self.risk)
        out["alpha"] = float(self.alpha)
        out["start"] = {"x": self.x0.tolist(), "P": self.P0.tolist()}
        if self.start_confidence is not None:
            out["start"]["confidence"] = float(self.start_confidence)
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
                f"chi2={self.chi2:.4g}, alpha={self.alpha:g}{'' if self.risk is None else f', risk={self.risk:g}'}"
                f"{'' if self.start_confidence is None else f', start_confidence={self.start_confidence:.4g}'})")


# -------------------------------------------------------------------- files
_TOP_KEYS = ("name", "description", "confidence", "chi2", "risk", "alpha", "start", "noise", "domain", "target",
             "obstacles", "horizon", "planner")
_TABLE_KEYS = {"start": (("x", "P"), ("confidence",)), "noise": (("W",), ("W_rate",)), "horizon": ((), ("K",))}


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
    for key in ("alpha", "confidence", "chi2", "risk"):
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
    if "confidence" in start and not _is_real(start["confidence"]):
        raise ScenarioFileError("start.confidence", f"must be a number, got {type(start['confidence']).__name__}: "
                                                    f"{start['confidence']!r}")
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
        risk=data.get("risk"),
        start_confidence=start.get("confidence"),
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
