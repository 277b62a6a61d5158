"""A study: what to run, declared in TOML or built in Python.

The TOML form (docs/studies.md has the full reference)::

    [study]
    name = "mine"
    scenarios = ["paper-multi", "random-polygons:2"]   # built-ins, files, family:count, family@seed
    seeds = [0, 1]                  # planner seeds
    alpha = [0.1, 1.0]
    K = [20]
    methods = ["ccp", "ipopt"]      # any registered method, or "none" (the warm start itself)
    time_limit = 120                # per smoothing call, s (optional)
    case_timeout = 600              # per case, s (optional)
    montecarlo = 0                  # Monte-Carlo runs per row (0 = off)

    [planner]                       # keywords of bn.plan; a list is a grid axis
    n_nodes = 300

    [solver.ccp]                    # keywords of bn.smooth for one method; a list is a grid axis
    max_iter = 30

    [[arm]]                         # optional: several sub-grids, each overriding
    planner = { n_nodes = [1000] }  # [planner] and methods; the study is their union
    methods = ["none"]

:meth:`Study.cases` expands it into :class:`~belief_nlp.study.cases.Case`
objects, one per (scenario, seed, alpha, K, planner setting); every case runs
all its method variants from one warm start.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Iterator, Mapping

from ..errors import ValidationError
from ..smoother.registry import DEFAULT_METHOD
from .cases import Case, Limits, MethodVariant, resolve_scenarios

__all__ = ["Study", "load_study", "builtin_studies"]

_LIMIT_KEYS = {f.name for f in fields(Limits)}
_STUDY_KEYS = {"name", "scenarios", "seeds", "alpha", "K", "methods", "description"} | _LIMIT_KEYS
#: Planner options whose single value is itself a list (a list of lists is then a grid).
_LIST_VALUED = {"eig_range"}
#: smooth() keywords that are never grid axes even when given as a list/table.
_NOT_GRID = {"solver_options"}


def _as_list(value: Any, name: str) -> list:
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValidationError(name, "must not be empty")
        return list(value)
    return [value]


def _grid(table: Mapping[str, Any], name: str, list_valued: set[str]) -> list[dict]:
    """All combinations of a table whose list values are axes (sorted keys: stable order)."""
    if not isinstance(table, Mapping):
        raise ValidationError(name, f"must be a table, got {type(table).__name__}")
    axes = []
    for key in sorted(table):
        v = table[key]
        if key in list_valued:
            is_axis = isinstance(v, (list, tuple)) and bool(v) and all(isinstance(i, (list, tuple)) for i in v)
        else:
            is_axis = isinstance(v, (list, tuple))
        if key in _NOT_GRID:
            is_axis = False
        axes.append([(key, i) for i in _as_list(v, f"{name}.{key}")] if is_axis else [(key, v)])
    return [dict(combo) for combo in itertools.product(*axes)] or [{}]


@dataclass
class Study:
    """A declarative solver-comparison study (see the module docstring).

    Attributes mirror the TOML keys (the budgets -- time_limit, case_timeout,
    montecarlo, montecarlo_substeps, fallback, tol -- in ``limits``, a
    :class:`~belief_nlp.study.cases.Limits`); ``planner`` and ``solver`` may hold lists
    (grid axes), ``arms`` optional overrides ``{"planner": {...}, "methods": [...],
    "name": ...}`` whose union is the study.
    """

    name: str = "study"
    scenarios: list[str] = field(default_factory=lambda: ["paper-multi"])
    seeds: list[int] = field(default_factory=lambda: [0])
    alpha: list[float] = field(default_factory=lambda: [0.1])
    K: list[int | None] = field(default_factory=lambda: [20])
    methods: list[str] = field(default_factory=lambda: [DEFAULT_METHOD])
    planner: dict = field(default_factory=dict)
    solver: dict = field(default_factory=dict)
    arms: list[dict] = field(default_factory=list)
    limits: Limits = field(default_factory=Limits)
    description: str = ""
    base_dir: str = "."      # where relative scenario files are looked up

    def __post_init__(self) -> None:
        self.scenarios = [str(s) for s in _as_list(self.scenarios, "study.scenarios")]
        self.seeds = _as_list(self.seeds, "study.seeds")
        self.alpha = [float(a) for a in _as_list(self.alpha, "study.alpha")]
        self.K = [None if k in (None, 0, "edges") else int(k) for k in _as_list(self.K, "study.K")]
        self.methods = [str(m) for m in _as_list(self.methods, "study.methods")]
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise ValidationError("study.seeds", f"seeds are integers >= 0, got {s!r:.40}")
        if not isinstance(self.solver, Mapping):
            raise ValidationError("solver", "must be a table of per-method tables")
        for arm in self.arms:
            unknown = set(arm) - {"planner", "methods", "name", "seeds", "alpha", "K", "scenarios"}
            if unknown:
                raise ValidationError("arm", f"unknown keys {sorted(unknown)}")

    # ------------------------------------------------------------- building
    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base_dir: str | os.PathLike = ".") -> "Study":
        """From the TOML tree (``[study]``, ``[planner]``, ``[solver.<method>]``, ``[[arm]]``)."""
        if not isinstance(data, Mapping) or "study" not in data:
            raise ValidationError("study", "a study file needs a [study] table")
        unknown_top = set(data) - {"study", "planner", "solver", "arm"}
        if unknown_top:
            raise ValidationError(sorted(unknown_top)[0], "unknown table; known: study, planner, solver, arm")
        st = dict(data["study"])
        unknown = set(st) - _STUDY_KEYS
        if unknown:
            raise ValidationError(f"study.{sorted(unknown)[0]}", f"unknown key; known: {', '.join(sorted(_STUDY_KEYS))}")
        limits = Limits(**{k: st.pop(k) for k in list(st) if k in _LIMIT_KEYS})
        return cls(**st, limits=limits, planner=dict(data.get("planner", {})), solver=dict(data.get("solver", {})),
                   arms=[dict(a) for a in data.get("arm", [])], base_dir=str(base_dir))

    def to_dict(self) -> dict:
        """The TOML tree of this study (``from_dict(to_dict())`` gives it back)."""
        st = {k: getattr(self, k) for k in sorted(_STUDY_KEYS - _LIMIT_KEYS)}
        st.update({k: v for k, v in asdict(self.limits).items() if v is not None})
        st["K"] = [0 if k is None else k for k in self.K]
        out: dict[str, Any] = {"study": st, "planner": dict(self.planner), "solver": dict(self.solver)}
        if self.arms:
            out["arm"] = [dict(a) for a in self.arms]
        return out

    # ------------------------------------------------------------ expansion
    def method_variants(self, methods: list[str]) -> list[MethodVariant]:
        """The method variants of a case: each method times the grid of its ``[solver.<method>]`` table."""
        out = []
        for m in methods:
            table = self.solver.get(m, {})
            axes = [k for k in sorted(table) if isinstance(table[k], (list, tuple)) and k not in _NOT_GRID]
            for opts in _grid(table, f"solver.{m}", set()):
                label = m + ("[" + ",".join(f"{k}={opts[k]}" for k in axes) + "]" if axes else "")
                out.append(MethodVariant(m, opts, label))
        labels = [v.label for v in out]
        if len(set(labels)) != len(labels):
            raise ValidationError("study.methods", f"a method is listed twice: {labels}")
        return out

    def cases(self) -> Iterator[Case]:
        """The cases, in a stable order (lazily: a long study is never held as a list)."""
        arms = self.arms or [{}]
        seen: set[str] = set()
        for arm in arms:
            planner = {**self.planner, **arm.get("planner", {})}
            variants = self.method_variants([str(m) for m in _as_list(arm.get("methods", self.methods), "arm.methods")])
            scen = resolve_scenarios([str(s) for s in arm.get("scenarios", self.scenarios)], self.base_dir)
            for sref, seed, alpha, K, popts in itertools.product(
                    scen, _as_list(arm.get("seeds", self.seeds), "arm.seeds"),
                    [float(a) for a in _as_list(arm.get("alpha", self.alpha), "arm.alpha")],
                    [None if k in (None, 0) else int(k) for k in _as_list(arm.get("K", self.K), "arm.K")],
                    _grid(planner, "planner", _LIST_VALUED)):
                case = Case(study=self.name, scenario=sref, seed=int(seed), alpha=alpha, K=K, planner=popts,
                            methods=tuple(variants), limits=self.limits, arm=str(arm.get("name", "")))
                if case.key in seen:       # arms may overlap: run each case once
                    continue
                seen.add(case.key)
                yield case

    def n_cases(self) -> int:
        """How many cases :meth:`cases` yields (expands once, keeps only keys)."""
        return sum(1 for _ in self.cases())


def builtin_studies() -> list[str]:
    """Names of the studies shipped in ``belief_nlp/study/builtin/``."""
    folder = Path(__file__).with_name("builtin")
    return sorted(p.stem for p in folder.glob("*.toml"))


def load_study(source: str | os.PathLike | Mapping | Study) -> Study:
    """A Study from a TOML file, a built-in study name (``builtin_studies()``), a dict or a Study."""
    if isinstance(source, Study):
        return source
    if isinstance(source, Mapping):
        return Study.from_dict(source)
    import tomllib

    path = Path(source)
    if not path.exists() and str(source) in builtin_studies():
        path = Path(__file__).with_name("builtin") / f"{source}.toml"
    if not path.exists():
        raise FileNotFoundError(2, "No such file", str(source))
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValidationError("study", f"{path}: not valid TOML ({exc})") from None
    return Study.from_dict(data, base_dir=path.parent)
