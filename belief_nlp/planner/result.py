"""PlanResult: what an IG-RRT* run returns, with JSON / NPZ save and load."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..belief import NATS_PER_BIT
from ..errors import ValidationError
from ..path import BeliefPath

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
    return float(v)


@dataclass(eq=False)
class PlanResult:
    """Outcome of :func:`belief_nlp.planner.plan`.

    Attributes
    ----------
    success : a path was found *and* passed :func:`belief_nlp.verify`.
    message : one line saying what happened (why it failed, if it did).
    path : the best :class:`~belief_nlp.BeliefPath` (S_k of each lossless
        transition, the noise model, ``meta`` with seed and options), or None.
    cost : planner cost of ``path`` = travel + alpha * information (inf if none).
    travel : length of the path, metres.
    information : sum of the edges' information terms in the metric's unit
        (entropy: nats or bits as ``info_unit``; wasserstein: metres;
        hellinger: dimensionless).
    alpha : the information weight used.
    metric, info_unit, noise : the cost configuration.
    cost_history : (n,) best cost with k = 1..n nodes in the tree
        (``cost_history[k-1]``; inf before the first solution). Non-increasing.
    first_solution_iteration : number of nodes in the tree when the first
        solution appeared (the authors' iteration ii), or None.
    tree : :class:`TreeView` of the final tree.
    stats : counts. ``nodes`` (in the tree, root included), ``attempts``
        (samples drawn), ``rejected_*`` (samples that got no node, by
        reason), ``parent_candidates`` / ``rewire_candidates``, ``rewires``,
        ``pruned`` / ``revived`` (branch-and-bound), ``goal_nodes``;
        ``edges_checked``: candidate edges given an exact collision decision;
        ``collision_checks``: (edge, obstacle) pairs that needed the iterative
        Theorem-1 minimiser (the rest were decided in closed form); the
        ``collision_*`` entries break the decisions down by layer.
    timings : seconds: ``sample``, ``candidates``, ``collision``, ``rewire``,
        ``prune``, ``verify``, ``total`` (wall) and ``cpu`` (process time).
    verification : ``VerificationReport.to_dict()`` of the returned path.
    options : the resolved planner options; seed : the seed;
    scenario : name of the scenario.
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
        a = self.alpha if alpha is None else float(alpha)
        if self.metric != "entropy":
            return self.travel + a * self.information
        return self.travel + a * self.information_nats / NATS_PER_BIT

    def cost_in_nats(self, alpha: float | None = None) -> float:
        """length + alpha * information_nats (entropy metric)."""
        a = self.alpha if alpha is None else float(alpha)
        return self.travel + a * self.information_nats

    # ----------------------------------------------------------- display
    def summary(self) -> str:
        head = "success" if self.success else "FAILED"
        lines = [f"IG-RRT* {head}: {self.message}"]
        if self.path is not None:
            lines.append(f"  cost {self.cost:.6g} = travel {self.travel:.6g} m + {self.alpha:g} * "
                         f"information {self.information:.6g} ({self.metric}, {self.info_unit})")
            lines.append(f"  path: {self.path.K} transitions; first solution at node "
                         f"{self.first_solution_iteration}")
        lines.append(f"  nodes {self.stats.get('nodes')}, attempts {self.stats.get('attempts')}, "
                     f"time {self.timings.get('total', float('nan')):.3g} s")
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
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise ValidationError("result", f"not a {_FORMAT} document")
        tree = data.get("tree")
        return cls(
            success=bool(data["success"]), message=str(data["message"]),
            path=BeliefPath.from_dict(data["path"]) if data.get("path") is not None else None,
            cost=_unnum(data["cost"]), travel=_unnum(data["travel"]), information=_unnum(data["information"]),
            alpha=float(data["alpha"]), metric=data["metric"], info_unit=data["info_unit"], noise=data["noise"],
            cost_history=np.array([_unnum(v) for v in data["cost_history"]], dtype=float),
            first_solution_iteration=data.get("first_solution_iteration"),
            tree=TreeView(np.array(tree["x"], float), np.array(tree["P"], float),
                          np.array(tree["parent"], np.int64), np.array(tree["cost"], float),
                          np.array(tree["live"], bool), np.array(tree["goal"], bool)) if tree else None,
            stats=dict(data.get("stats") or {}), timings=dict(data.get("timings") or {}),
            verification=data.get("verification"), options=dict(data.get("options") or {}),
            seed=data.get("seed"), scenario=str(data.get("scenario", "")),
        )

    def save(self, path: str | Path) -> Path:
        """Write as ``.json`` (one document) or ``.npz`` (arrays + a JSON header);
        :meth:`load` reads either back."""
        path = Path(path)
        if path.suffix == ".json":
            path.write_text(json.dumps(self.to_dict(), allow_nan=False))
        elif path.suffix == ".npz":
            # The path (a few dozen numbers) rides in the JSON header; the tree and
            # the history, which grow with the node count, are arrays.
            header = self._header()
            header["path"] = self.path.to_dict() if self.path is not None else None
            arrays: dict[str, np.ndarray] = {"header": np.array(json.dumps(header, allow_nan=False)),
                                             "cost_history": np.asarray(self.cost_history, float)}
            if self.tree is not None:
                arrays.update({f"tree_{k}": v for k, v in self.tree.to_arrays().items()})
            np.savez_compressed(path, **arrays)
        else:
            raise ValidationError("path", f"plan results are saved as .json or .npz, got {path.suffix!r}")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "PlanResult":
        """Read a result written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise ValidationError("path", f"no such file: {path}")
        if path.suffix == ".npz":
            try:
                with np.load(path, allow_pickle=False) as z:
                    data = json.loads(str(z["header"]))
                    data["cost_history"] = z["cost_history"].tolist()
                    data["tree"] = ({k: z[f"tree_{k}"] for k in ("x", "P", "parent", "cost", "live", "goal")}
                                    if "tree_x" in z.files else None)
            except (OSError, ValueError, KeyError) as exc:
                raise ValidationError("path", f"{path}: not a plan-result NPZ file: {exc}") from exc
            return cls.from_dict(data)
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValidationError("path", f"{path}: malformed JSON: {exc}") from exc
        return cls.from_dict(data)
