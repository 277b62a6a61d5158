"""Cases: one (scenario, seed, alpha, K, planner setting) of a study, with a stable key.

A :class:`Case` is plain data (picklable, JSON-able): a worker process or a
Dask worker on another machine rebuilds everything from it. Its
:attr:`Case.key` is a hash of what determines its results -- the scenario's
content, seed, alpha, K, planner options, method variants and limits -- and
not of the study's name or the order of cases, so rerunning a study, or a
changed study that shares cases, skips what is already on disk.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import Any

from ..errors import ValidationError
from ..scenario import Scenario, list_scenarios, load_scenario, scenario_from_dict

__all__ = ["Case", "Limits", "MethodVariant", "ScenarioRef", "resolve_scenarios", "case_from_dict", "canonical_json"]


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no spaces: equal data, equal text (the key's input)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True, default=str)


def _digest(scenario: Scenario) -> str:
    return hashlib.sha256(canonical_json(scenario.to_dict()).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ScenarioRef:
    """Where a case's scenario comes from.

    Attributes
    ----------
    kind : str
        ``"builtin"`` (``ref`` is the name), ``"family"`` (``ref`` is
        ``"family@seed"``) or ``"file"`` (the scenario's tree travels in
        ``data``: remote workers need no file).
    ref : str
        The name, family reference or file the scenario came from.
    label : str
        The ``scenario`` column of the records.
    digest : str
        Hash of the scenario's content; a worker checks it.
    data : dict or None
        The scenario's tree for ``kind="file"``.
    """

    kind: str
    ref: str
    label: str
    digest: str
    data: dict | None = field(default=None, compare=False)

    def load(self) -> Scenario:
        """The scenario (checked against the digest)."""
        if self.kind == "builtin":
            sc = load_scenario(self.ref)
        elif self.kind == "family":
            from ..families import generate

            family, _, seed = self.ref.partition("@")
            sc = generate(family, int(seed))
        elif self.kind == "file":
            sc = scenario_from_dict(self.data, source=self.ref)
        else:
            raise ValidationError("scenario", f"unknown scenario kind {self.kind!r}")
        if _digest(sc) != self.digest:
            raise ValidationError("scenario", f"{self.label}: the scenario differs from the one the study was "
                                              f"expanded with (library version changed?)")
        return sc


def resolve_scenarios(specs: list[str], base_dir: str | os.PathLike = ".") -> list[ScenarioRef]:
    """Scenario spec strings -> references: built-in names, files (relative to
    ``base_dir``), ``family:count`` and ``family@seed``."""
    from ..families import generate, is_family_spec, parse_family_spec

    out = []
    builtins = set(list_scenarios())
    for spec in specs:
        if spec in builtins:
            out.append(ScenarioRef("builtin", spec, spec, _digest(load_scenario(spec))))
        elif is_family_spec(spec):
            for family, seed in parse_family_spec(spec):
                sc = generate(family, seed)
                out.append(ScenarioRef("family", f"{family}@{seed}", sc.name, _digest(sc)))
        else:
            path = Path(spec)
            if not path.is_absolute():
                path = Path(base_dir) / path
            if not path.exists():
                raise ValidationError("scenarios", f"{spec!r} is not a built-in ({', '.join(sorted(builtins))}), "
                                                   f"a family spec (family:count) or an existing file")
            sc = load_scenario(path)
            out.append(ScenarioRef("file", str(path), sc.name or path.stem, _digest(sc), sc.to_dict()))
    return out


@dataclass(frozen=True)
class MethodVariant:
    """A smoothing method with its ``smooth`` keywords; ``label`` is the ``method`` column."""

    method: str
    options: dict = field(default_factory=dict)
    label: str = ""

    def __post_init__(self) -> None:
        if not self.label:
            object.__setattr__(self, "label", self.method)


@dataclass(frozen=True)
class Limits:
    """Budgets and options shared by every case of a study (the ``[study]`` keys of the same names).

    time_limit : seconds per smoothing call (None: the method's own budget).
    case_timeout : seconds per case (process-pool workers; docs/studies.md).
    montecarlo, montecarlo_substeps : simulated runs per row (0: off), samples per transition.
    fallback : "edges" (one step per edge when the K-step warm start fails) or "none".
    tol : the smoother's relative tolerance.
    """

    time_limit: float | None = None
    case_timeout: float | None = None
    montecarlo: int = 0
    montecarlo_substeps: int = 20
    fallback: str = "edges"
    tol: float = 1e-4

    def __post_init__(self) -> None:
        if self.fallback not in ("edges", "none"):
            raise ValidationError("study.fallback", f"must be 'edges' or 'none', got {self.fallback!r}")
        m = self.montecarlo
        if isinstance(m, bool) or not isinstance(m, int) or m < 0:
            raise ValidationError("study.montecarlo", f"must be an integer >= 0, got {m!r}")


@dataclass(frozen=True)
class Case:
    """One unit of work: plan, build the warm start, smooth with every variant, verify."""

    study: str
    scenario: ScenarioRef
    seed: int
    alpha: float
    K: int | None
    planner: dict
    methods: tuple[MethodVariant, ...]
    limits: Limits = field(default_factory=Limits)
    arm: str = ""

    def identity(self) -> dict:
        """What determines the case's results (the key's input)."""
        return {"scenario": self.scenario.label, "scenario_digest": self.scenario.digest, "seed": self.seed,
                "alpha": self.alpha, "K": self.K, "planner": self.planner,
                "methods": [[m.label, m.method, m.options] for m in self.methods],
                # the case's wall-clock cap changes no result that finishes: not part of the key
                **{k: v for k, v in asdict(self.limits).items() if k != "case_timeout"}}

    @cached_property
    def key(self) -> str:
        """Stable 16-hex-digit key of the case."""
        return hashlib.sha256(canonical_json(self.identity()).encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        """JSON-able form; :func:`case_from_dict` rebuilds the case (each record carries it)."""
        d = asdict(self)
        d["methods"] = [asdict(m) for m in self.methods]
        return d


def case_from_dict(data: dict | str) -> Case:
    """The case a record came from (``data`` = the record's ``case`` column, JSON text or dict)."""
    if isinstance(data, str):
        data = json.loads(data)
    data = dict(data)
    data["scenario"] = ScenarioRef(**data["scenario"])
    data["methods"] = tuple(MethodVariant(**m) for m in data["methods"])
    limits = dict(data.get("limits", {}))
    for f in fields(Limits):       # records written before the budgets were grouped kept them flat
        if f.name in data:
            limits[f.name] = data.pop(f.name)
    data["limits"] = Limits(**limits)
    return Case(**data)
