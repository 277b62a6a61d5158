"""PlanResult: what an IG-RRT* run returns, with JSON / NPZ save and load."""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from .._limits import check_npz, load_json, parse_document
from ..belief import NATS_PER_BIT
from ..errors import ScenarioFileError, ValidationError
from ..path import BeliefPath, _alpha, _values_equal
from ..scenario_validate import _finite

__all__ = ["PlanResult", "TreeView"]

_FORMAT = "belief_nlp.PlanResult/1"


@dataclass(eq=False)
class TreeView:
    """The final tree, for plotting and inspection (plain arrays, n nodes).

    Attributes
    ----------
    x : (n, d) node means; P : (n, d, d) node (posterior) covariances.
    parent : (n,) int, -1 for the root (node 0).
    cost : (n,) cost-to-come.
    live : (n,) False for nodes removed by branch-and-bound.
    goal : (n,) True where the node's ellipse lies inside the target.
    """

    x: np.ndarray
    P: np.ndarray
    parent: np.ndarray
    cost: np.ndarray
    live: np.ndarray
    goal: np.ndarray

    def __post_init__(self) -> None:
        # private read-only copies, in the dtypes the fields document
        for name, dtype in (("x", float), ("P", float), ("parent", np.int64), ("cost", float), ("live", bool),
                            ("goal", bool)):
            try:
                arr = np.array(getattr(self, name), dtype=dtype)
            except (TypeError, ValueError, OverflowError) as exc:
                raise ValidationError(f"tree.{name}", f"must be an array of {np.dtype(dtype).name}: "
                                                      f"{str(exc)[:200]}") from exc
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        n = self.x.shape[0] if self.x.ndim == 2 else -1
        d = self.x.shape[1] if self.x.ndim == 2 else 0
        if n < 0:
            raise ValidationError("tree.x", f"must have shape (n, d), got {self.x.shape}")
        if self.P.shape != (n, d, d):
            raise ValidationError("tree.P", f"must have shape {(n, d, d)}, got {self.P.shape}")
        for name in ("parent", "cost", "live", "goal"):
            if getattr(self, name).shape != (n,):
                raise ValidationError(f"tree.{name}", f"must have shape {(n,)}, got {getattr(self, name).shape}")
        for name in ("x", "P"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValidationError(f"tree.{name}", "contains NaN or infinite values")
        if n and (np.any(self.parent < -1) or np.any(self.parent >= n)):
            raise ValidationError("tree.parent", f"entries must be -1 or node indices below {n}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TreeView):
            return NotImplemented
        return all(_values_equal(a, b) for a, b in zip(self.to_arrays().values(), other.to_arrays().values()))

    __hash__ = None  # type: ignore[assignment]

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def edges(self) -> np.ndarray:
        """(n-1, 2, d) segments parent -> child, for plotting."""
        child = np.nonzero(self.parent >= 0)[0]
        return np.stack([self.x[self.parent[child]], self.x[child]], axis=1)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"x": self.x, "P": self.P, "parent": self.parent, "cost": self.cost, "live": self.live,
                "goal": self.goal}


def _num(v: float) -> float | str:
    """JSON-safe float (inf/nan as strings, since JSON has neither)."""
    v = float(v)
    return v if math.isfinite(v) else repr(v)


def _unnum(v: Any) -> float:
    """Inverse of :func:`_num`: a number, or one of the strings 'inf', '-inf', 'nan'."""
    if isinstance(v, str) and v not in ("inf", "-inf", "nan"):
        raise ValidationError("result", f"expected a number or 'inf'/'nan', got {v[:40]!r}")
    if isinstance(v, bool) or not isinstance(v, (str, int, float)):
        raise ValidationError("result", f"expected a number, got {type(v).__name__}")
    return float(v)


def _check_risk(risk: Any) -> None:
    """A ``PlanResult.risk`` record (as :mod:`~belief_nlp.planner.budget` writes it), or ValidationError."""
    if not isinstance(risk, dict):
        raise ValidationError("risk", f"must be a dict or None, got {type(risk).__name__}")
    for key in ("budget", "collision_chi2", "target_chi2", "bound"):
        v = risk.get(key)
        if not _finite(v) and not (key == "bound" and v is None):
            raise ValidationError(f"risk.{key}", f"must be a finite number, got {v!r:.40}")
    if not isinstance(risk.get("rounds"), list):
        raise ValidationError("risk.rounds", "must be a list of planning rounds")


@dataclass(eq=False)
class PlanResult:
    """Outcome of :func:`belief_nlp.plan` (IG-RRT*).

    Built by the planner; saved with :meth:`save` (JSON or NPZ) and reloaded
    equal with :meth:`load`.

    Attributes
    ----------
    success : bool
        A path was found *and* passed :func:`belief_nlp.verify`.
    message : str
        One line saying what happened (why it failed, if it did).
    path : BeliefPath or None
        The best path (S_k of each lossless transition, the noise model,
        ``meta`` with seed and options), or None.
    cost : float
        Planner cost of ``path`` = travel + alpha * information (inf if none).
    travel : float
        Length of the path, metres.
    information : float
        Sum of the edges' information terms in the metric's unit (entropy:
        nats or bits as ``info_unit``; wasserstein: metres; hellinger:
        dimensionless).
    alpha : float
        The information weight used.
    metric, info_unit, noise : str
        The cost configuration.
    cost_history : ndarray, shape (n,)
        Best cost with k = 1..n nodes in the tree (``cost_history[k-1]``; inf
        before the first solution). Non-increasing. OMPL baseline: OMPL's best
        path length at each improvement (the costs of ``cost_trace``).
    first_solution_iteration : int or None
        Number of nodes in the tree when the first solution appeared (the
        authors' iteration ii), or None.
    tree : TreeView or None
        The final tree (nodes, parents, costs, beliefs).
    stats : dict
        Counts. ``nodes`` (in the tree, root included), ``attempts`` (samples
        drawn), ``rejected_*`` (samples that got no node, by reason),
        ``parent_candidates`` / ``rewire_candidates``, ``rewires``,
        ``pruned`` / ``revived`` (branch-and-bound), ``goal_nodes``;
        ``edges_checked``: candidate edges given an exact collision decision;
        ``collision_checks``: (edge, obstacle) pairs that needed the
        iterative Theorem-1 minimiser (the rest were decided in closed form);
        ``undecided_pairs``: those of them whose rigorous bounds decided
        nothing (rejected as collisions, never passed); the ``collision_*``
        entries break the decisions down by layer. ``backend``: the
        IG-RRT* backend that ran (``"numpy"`` or ``"numba"``).
    timings : dict
        Seconds: ``sample``, ``candidates``, ``collision``, ``rewire``,
        ``prune``, ``verify``, ``total`` (wall) and ``cpu`` (process time).
        The numba backend adds ``compiled`` (its compiled calls, which do
        what ``sample`` to ``collision`` time in numpy; ``collision`` is then
        the exact fallback) and ``compile`` (loading the compiled attempt,
        about 12 s on a machine's first numba plan; ``total``, ``cpu``, the
        time limit and ``cost_trace`` do not count it).
    verification : dict or None
        ``VerificationReport.to_dict()`` of the returned path.
    options : dict
        The resolved planner options.
    seed : int or None
        The seed of the random generator.
    scenario : str
        Name of the scenario.
    planner : str
        ``"igrrt"`` (IG-RRT*) or ``"ompl:<Class>"`` (the OMPL baseline,
        :mod:`~belief_nlp.planner.ompl_baseline`).
    cost_trace : list
        The anytime curve in time: ``[[seconds since the start, best cost],
        ...]`` at each improvement (IG-RRT*: its planner cost; OMPL: OMPL's
        objective, the path length in metres).
    risk : dict or None
        For a plan within an end-to-end collision-probability budget
        (``plan(..., risk=Delta)``, :mod:`~belief_nlp.planner.budget`):
        ``budget`` (Delta), ``kind`` ("steps"), ``met``, ``bound`` (the
        path's certified bound on a collision at the step times,
        ``path_risk(scenario, path).step_time``, <= budget; None when not
        met), ``collision_chi2`` (the planner's collision level),
        ``target_chi2`` (the scenario's, kept for the target) and
        ``rounds`` (each planning round: ``n_pairs`` (the pairs its level is
        the warm start level of), ``collision_chi2``, ``found``, ``K``,
        ``pairs_needed`` (J max(horizon, K)), ``bound``, ``seconds``). None
        without a budget.
    """

    success: bool
    message: str
    path: BeliefPath | None
    cost: float
    travel: float
    information: float
    alpha: float
    metric: str
    info_unit: str
    noise: str
    cost_history: np.ndarray
    first_solution_iteration: int | None
    tree: TreeView | None
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    verification: dict | None = None
    options: dict = field(default_factory=dict)
    seed: int | None = None
    scenario: str = ""
    planner: str = "igrrt"
    cost_trace: list = field(default_factory=list)
    risk: dict | None = None

    def __post_init__(self) -> None:
        if self.path is not None and not isinstance(self.path, BeliefPath):
            raise ValidationError("path", f"must be a BeliefPath or None, got {type(self.path).__name__}")
        if self.tree is not None and not isinstance(self.tree, TreeView):
            raise ValidationError("tree", f"must be a TreeView or None, got {type(self.tree).__name__}")
        try:
            history = np.array(self.cost_history, dtype=float).reshape(-1)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValidationError("cost_history", f"must be a list of numbers: {str(exc)[:200]}") from exc
        history.flags.writeable = False
        self.cost_history = history
        try:
            trace = [[float(t), float(c)] for t, c in self.cost_trace]
        except (TypeError, ValueError) as exc:
            raise ValidationError("cost_trace", f"must be a list of [seconds, cost] pairs: {str(exc)[:200]}") from exc
        self.cost_trace = trace
        if self.risk is not None:
            _check_risk(self.risk)

    def __eq__(self, other: object) -> bool:
        """Field by field, NaN equal to NaN (a failed run's travel is NaN), so
        that a result reloaded from a file compares equal to the original."""
        if not isinstance(other, PlanResult):
            return NotImplemented
        return all(_values_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]

    # ------------------------------------------------------------- units
    @property
    def information_nats(self) -> float:
        """Entropy information in nats (entropy metric only, else nan)."""
        if self.metric != "entropy":
            return float("nan")
        return self.information * (NATS_PER_BIT if self.info_unit == "bits" else 1.0)

    def cost_in_authors_units(self, alpha: float | None = None) -> float:
        """The path's cost as the authors' IG-RRT* reports it.

        Entropy: length + (alpha/2)(log2 det P_hat - log2 det P) summed over
        edges = length + alpha * information_nats / ln 2 ("metres + alpha/2 *
        bits", the bits being those of the log-determinant). For the other
        metrics the units agree already. ``alpha`` defaults to this run's.
        """
        a = self.alpha if alpha is None else _alpha(alpha)
        if self.metric != "entropy":
            return self.travel + a * self.information
        return self.travel + a * self.information_nats / NATS_PER_BIT

    def cost_in_nats(self, alpha: float | None = None) -> float:
        """length + alpha * information_nats (entropy metric)."""
        a = self.alpha if alpha is None else _alpha(alpha)
        return self.travel + a * self.information_nats

    # ----------------------------------------------------------- display
    def summary(self) -> str:
        """A few lines for people: success, cost and its parts, path length, nodes and time.

        Returns
        -------
        str
            Lines separated by newlines, no trailing newline.
        """
        head = "success" if self.success else "FAILED"
        name = "IG-RRT*" if self.planner == "igrrt" else self.planner
        lines = [f"{name} {head}: {self.message}"]
        if self.path is not None:
            lines.append(f"  cost {self.cost:.6g} = travel {self.travel:.6g} m + {self.alpha:g} * "
                         f"information {self.information:.6g} ({self.metric}, {self.info_unit})")
            first = "" if self.planner != "igrrt" else f"; first solution at node {self.first_solution_iteration}"
            lines.append(f"  path: {self.path.K} transitions{first}")
            risk = (self.verification or {}).get("risk_step_time")
            if risk is not None:
                lines.append(f"  collision probability <= {risk:.3g} at the step times (certified; Boole over "
                             f"transition-hazard pairs, bn.verify(...).risk)")
        if self.risk is not None:
            r = self.risk
            bound = "not met" if r.get("bound") is None else f"certified bound {r['bound']:.3g}"
            lines.append(f"  risk budget {r.get('budget'):g} ({r.get('kind')}): {bound}; collisions at chi2 = "
                         f"{r.get('collision_chi2'):.4g}, target at {r.get('target_chi2'):.4g}, "
                         f"{len(r.get('rounds') or [])} planning round(s)")
        if self.planner == "igrrt":
            lines.append(f"  nodes {self.stats.get('nodes')}, attempts {self.stats.get('attempts')}, "
                         f"time {self.timings.get('total', float('nan')):.3g} s")
        else:
            lines.append(f"  iterations {self.stats.get('iterations')}, motions checked "
                         f"{self.stats.get('motion_checks')}, time {self.timings.get('total', float('nan')):.3g} s")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"PlanResult(success={self.success}, cost={self.cost:.6g}, nodes={self.stats.get('nodes')}, "
                f"message={self.message!r})")

    # ------------------------------------------------------------- files
    def _header(self) -> dict[str, Any]:
        return {
            "format": _FORMAT,
            "success": bool(self.success),
            "message": self.message,
            "cost": _num(self.cost),
            "travel": _num(self.travel),
            "information": _num(self.information),
            "alpha": float(self.alpha),
            "metric": self.metric,
            "info_unit": self.info_unit,
            "noise": self.noise,
            "first_solution_iteration": self.first_solution_iteration,
            "stats": self.stats,
            "timings": self.timings,
            "verification": self.verification,
            "options": self.options,
            "seed": self.seed,
            "scenario": self.scenario,
            "planner": self.planner,
            "cost_trace": self.cost_trace,
            "risk": self.risk,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict (infinite costs as the strings 'inf')."""
        out = self._header()
        out["cost_history"] = [_num(v) for v in self.cost_history]
        out["path"] = self.path.to_dict() if self.path is not None else None
        out["tree"] = ({k: v.tolist() for k, v in self.tree.to_arrays().items()}
                       if self.tree is not None else None)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PlanResult":
        """A result from :meth:`to_dict` output; faults raise ValidationError."""
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise ValidationError("result", f"not a {_FORMAT} document")
        try:
            tree = data.get("tree")
            path = data.get("path")
            return cls(
                success=bool(data["success"]), message=str(data["message"]),
                path=BeliefPath.from_dict(path) if path is not None else None,
                cost=_unnum(data["cost"]), travel=_unnum(data["travel"]), information=_unnum(data["information"]),
                alpha=_unnum(data["alpha"]), metric=str(data["metric"]), info_unit=str(data["info_unit"]),
                noise=str(data["noise"]),
                cost_history=np.array([_unnum(v) for v in data["cost_history"]], dtype=float),
                first_solution_iteration=data.get("first_solution_iteration"),
                tree=TreeView(tree["x"], tree["P"], tree["parent"], tree["cost"], tree["live"], tree["goal"])
                if tree else None,
                stats=dict(data.get("stats") or {}), timings=dict(data.get("timings") or {}),
                verification=data.get("verification"), options=dict(data.get("options") or {}),
                seed=data.get("seed"), scenario=str(data.get("scenario", "")),
                planner=str(data.get("planner", "igrrt")), cost_trace=list(data.get("cost_trace") or []),
                risk=data.get("risk"),
            )
        except ValidationError:
            raise
        except KeyError as exc:
            raise ValidationError(f"result.{exc.args[0]}", "missing") from exc
        except (TypeError, ValueError, IndexError, AttributeError) as exc:
            raise ValidationError("result", f"malformed {_FORMAT} document: {str(exc)[:200]}") from exc

    def save(self, path: str | os.PathLike) -> Path:
        """Write as ``.json`` (one document) or ``.npz`` (arrays + a JSON header);
        :meth:`load` reads either back. A file that cannot be written raises
        :class:`~belief_nlp.errors.ScenarioFileError` (field ``path``)."""
        if not isinstance(path, (str, os.PathLike)):
            raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
        path = Path(path)
        if path.suffix not in (".json", ".npz"):
            raise ValidationError("path", f"plan results are saved as .json or .npz, got {path.suffix!r}")
        try:
            if path.suffix == ".json":
                text = json.dumps(self.to_dict(), allow_nan=False)
            else:
                # The path (a few dozen numbers) rides in the JSON header; the tree and
                # the history, which grow with the node count, are arrays.
                header = self._header()
                header["path"] = self.path.to_dict() if self.path is not None else None
                text = json.dumps(header, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValidationError("result", f"cannot be written as JSON: {exc}") from exc
        try:
            if path.suffix == ".json":
                path.write_text(text)
            else:
                arrays: dict[str, np.ndarray] = {"header": np.array(text),
                                                 "cost_history": np.asarray(self.cost_history, float)}
                if self.tree is not None:
                    arrays.update({f"tree_{k}": v for k, v in self.tree.to_arrays().items()})
                np.savez_compressed(path, **arrays)
        except OSError as exc:
            raise ScenarioFileError("path", f"cannot write {str(path)[:200]}: {exc}") from exc
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "PlanResult":
        """Read a result written by :meth:`save` (limits as :meth:`BeliefPath.load`).

        File faults raise :class:`~belief_nlp.errors.ScenarioFileError`
        (field ``path``), bad contents :class:`~belief_nlp.errors.ValidationError`.
        """
        if not isinstance(path, (str, os.PathLike)):
            raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
        path = Path(path)
        if path.suffix != ".npz":
            return cls.from_dict(load_json(path, "path"))
        check_npz(path, "path")
        try:
            with np.load(path, allow_pickle=False) as z:
                header = z["header"]
                history = z["cost_history"]
                tree = ({k: z[f"tree_{k}"] for k in ("x", "P", "parent", "cost", "live", "goal")}
                        if "tree_x" in z.files else None)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ScenarioFileError("path", f"{str(path)[:200]}: not a plan-result NPZ file: {str(exc)[:200]}") from exc
        if header.ndim != 0 or header.dtype.kind != "U":
            raise ValidationError("result", "the NPZ header must be a single string")
        data = parse_document(str(header), "json", f"{str(path)[:200]} (header)", "path")
        if not isinstance(data, dict):
            raise ValidationError("result", f"not a {_FORMAT} document")
        data["cost_history"] = history.tolist() if history.dtype.kind in "iuf" else history
        data["tree"] = tree
        return cls.from_dict(data)
