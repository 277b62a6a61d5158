"""Figures for scenarios, belief paths, planner trees and cost curves (matplotlib).

The figures follow the smoothing paper: 90 % (``scenario.chi2``) prior
confidence ellipses in blue, posterior ellipses in black (Figs. 2-3), cost
against CCP iteration (Fig. 4), and a GIF of the path evolving over the CCP
iterations (the paper's videos).

Conventions
-----------
* Nothing here calls ``plt.show()`` or picks a backend. Scripts choose one
  (``matplotlib.use("Agg")`` for headless use); notebooks display as usual.
* Every plotting function takes an optional ``ax``; without one it opens a new
  figure. Figure-level functions return ``(fig, ax)``; the primitives
  :func:`plot_ellipse` and :func:`plot_ellipses` return the artist they add.
* Artists carry a ``gid`` so they can be found and restyled afterwards with
  :func:`find_artists`: ``"domain"``, ``"obstacle"``, ``"target"``,
  ``"start"``, ``"mean-path"``, ``"prior-ellipses"``, ``"posterior-ellipses"``,
  ``"tree-edges"``, ``"tree-nodes"``, ``"tree-ellipses"``, ``"best-path"``.
* 3-D scenarios are drawn on 3-D axes (``mpl_toolkits.mplot3d``): polytopes as
  translucent facets of their convex hulls (``scipy.spatial.ConvexHull``,
  coplanar triangles merged into one polygon per face), confidence ellipsoids
  as coarse translucent meshes. Passing a 2-D axes for a 3-D scenario (or the
  reverse) raises ``ValueError``.
* Open figures are the caller's to close (``plt.close(fig)``), except the one
  :func:`animate_smoothing` opens for itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.colors import to_rgba
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Polygon
from matplotlib.ticker import MaxNLocator

__all__ = [
    "animate_smoothing",
    "find_artists",
    "plot_anytime",
    "plot_belief_path",
    "plot_cost_history",
    "plot_ellipse",
    "plot_ellipses",
    "plot_scenario",
    "plot_tree",
    "save_figure",
]


# ------------------------------------------------------------------ helpers
def _is_3d(ax) -> bool:
    return getattr(ax, "name", "") == "3d"


def _axes_for(dim: int, ax=None):
    """Return (fig, ax): the given axes (checked against ``dim``) or new ones."""
    if dim not in (2, 3):
        raise ValueError(f"only 2-D and 3-D plots are supported, got dimension {dim}")
    if ax is not None:
        if dim == 3 and not _is_3d(ax):
            raise ValueError("a 3-D plot needs 3-D axes (fig.add_subplot(projection='3d'))")
        if dim == 2 and _is_3d(ax):
            raise ValueError("a 2-D plot cannot be drawn on 3-D axes")
        return ax.figure, ax
    if dim == 3:
        fig = plt.figure(figsize=(6.4, 5.6))
        return fig, fig.add_subplot(projection="3d")
    return plt.subplots(figsize=(5.5, 5.5))


def find_artists(ax, gid: str) -> list:
    """All artists of ``ax`` whose ``gid`` is ``gid`` (see the module docstring)."""
    return [a for a in ax.get_children() if a.get_gid() == gid]


def _semi_axes(P: np.ndarray, chi2: float) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axis lengths (ascending) and unit directions (columns) of the
    ellipse {y : (y-x)^T P^-1 (y-x) <= chi2}."""
    P = np.asarray(P, dtype=float)
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    return np.sqrt(chi2 * np.clip(lam, 0.0, None)), V


def _ellipse_patch(x: np.ndarray, P: np.ndarray, chi2: float, **style: Any) -> Ellipse:
    r, V = _semi_axes(P, chi2)
    major = V[:, 1]
    angle = float(np.degrees(np.arctan2(major[1], major[0])))
    return Ellipse(xy=(float(x[0]), float(x[1])), width=2 * r[1], height=2 * r[0], angle=angle, **style)


def _ellipsoid_quads(x: np.ndarray, P: np.ndarray, chi2: float, n_lon: int = 16, n_lat: int = 8) -> np.ndarray:
    """(n_lon * n_lat, 4, 3) quadrilaterals meshing the surface of a 3-D ellipsoid."""
    r, V = _semi_axes(P, chi2)
    u = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    v = np.linspace(0.0, np.pi, n_lat + 1)
    sphere = np.stack([np.outer(np.cos(u), np.sin(v)),
                       np.outer(np.sin(u), np.sin(v)),
                       np.outer(np.ones_like(u), np.cos(v))], axis=-1)
    pts = np.asarray(x, dtype=float) + (sphere * r) @ V.T  # y = x + V diag(r) s
    quads = np.stack([pts[:-1, :-1], pts[1:, :-1], pts[1:, 1:], pts[:-1, 1:]], axis=2)
    return quads.reshape(-1, 4, 3)


def _hull_facets(V: np.ndarray) -> list[np.ndarray]:
    """Faces of the convex hull of 3-D points, each an ordered (m, 3) polygon.

    Qhull returns triangles; triangles on the same plane are merged so a box
    shows six squares rather than twelve triangles.
    """
    from scipy.spatial import ConvexHull

    V = np.asarray(V, dtype=float)
    hull = ConvexHull(V)
    eqs = hull.equations
    tol = 1e-8 * (1.0 + float(np.max(np.abs(V))))
    done = np.zeros(len(eqs), dtype=bool)
    facets = []
    for i, eq in enumerate(eqs):
        if done[i]:
            continue
        same = np.all(np.abs(eqs - eq) <= tol, axis=1)
        done |= same
        pts = V[np.unique(hull.simplices[same])]
        centre = pts.mean(axis=0)
        e1 = pts[0] - centre
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(eq[:3], e1)
        rel = pts - centre
        facets.append(pts[np.argsort(np.arctan2(rel @ e2, rel @ e1))])
    return facets


def _add_polytope(ax, poly, facecolor, edgecolor, linewidth: float, gid: str, zorder: float = 1.0):
    """Draw a bounded polytope: a Polygon patch in 2-D, hull facets in 3-D."""
    if _is_3d(ax):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        coll = Poly3DCollection(_hull_facets(poly.vertices), facecolors=facecolor, edgecolors=edgecolor,
                                linewidths=linewidth)
        coll.set_gid(gid)
        ax.add_collection3d(coll)
        return coll
    patch = Polygon(poly.vertices, closed=True, facecolor=facecolor, edgecolor=edgecolor,
                    linewidth=linewidth, zorder=zorder, gid=gid)
    ax.add_patch(patch)
    return patch


def _plot_polyline(ax, pts: np.ndarray, **style: Any):
    """ax.plot for (n, 2) or (n, 3) points; returns the Line2D."""
    pts = np.asarray(pts, dtype=float)
    (line,) = ax.plot(*pts.T, **style)
    return line


# --------------------------------------------------------------- ellipses
def plot_ellipse(ax, x, P, chi2: float, **style: Any):
    """Draw the confidence ellipse {y : (y-x)^T P^-1 (y-x) <= chi2}.

    2-D axes: a :class:`matplotlib.patches.Ellipse` whose semi-axes are
    ``sqrt(chi2 * eig(P))`` along the eigenvectors of ``P`` (outline only
    unless ``facecolor`` is given; ``color`` sets the outline). 3-D axes: the
    ellipsoid as one translucent mesh (see :func:`plot_ellipses`). A singular
    ``P`` gives a flat (or point) ellipse. Returns the artist.
    """
    x = np.asarray(x, dtype=float)
    if _is_3d(ax):
        return plot_ellipses(ax, x[None], np.asarray(P, dtype=float)[None], chi2, **style)
    style = dict(style)
    color = style.pop("color", None)
    style.setdefault("facecolor", "none")
    style.setdefault("edgecolor", color if color is not None else "black")
    style.setdefault("linewidth", 0.8)
    patch = _ellipse_patch(x, P, chi2, **style)
    ax.add_patch(patch)
    return patch


def plot_ellipses(ax, xs, Ps, chi2: float, **style: Any):
    """Draw many confidence ellipses as a single collection (fast).

    ``xs`` is (n, d) centres, ``Ps`` (n, d, d) covariances. 2-D: a
    :class:`~matplotlib.collections.PatchCollection` of ellipses (outline only
    by default; ``color`` sets the outline, other keywords go to the
    collection). 3-D: a ``Poly3DCollection`` meshing every ellipsoid
    (``color`` sets the surface; default alpha 0.15). Returns the collection.
    """
    xs = np.asarray(xs, dtype=float)
    Ps = np.asarray(Ps, dtype=float)
    if xs.ndim != 2 or Ps.shape != (xs.shape[0], xs.shape[1], xs.shape[1]):
        raise ValueError(f"need xs (n, d) and Ps (n, d, d), got {xs.shape} and {Ps.shape}")
    style = dict(style)
    color = style.pop("color", None)
    if _is_3d(ax):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        quads = [_ellipsoid_quads(x, P, chi2) for x, P in zip(xs, Ps)]
        style.setdefault("facecolor", color if color is not None else "tab:blue")
        style.setdefault("edgecolor", "none")
        style.setdefault("alpha", 0.15)
        coll = Poly3DCollection(np.concatenate(quads) if quads else np.zeros((0, 4, 3)), **style)
        ax.add_collection3d(coll)
        return coll
    style.setdefault("facecolor", "none")
    style.setdefault("edgecolor", color if color is not None else "black")
    style.setdefault("linewidth", 0.8)
    coll = PatchCollection([_ellipse_patch(x, P, chi2) for x, P in zip(xs, Ps)], **style)
    ax.add_collection(coll)
    return coll


# --------------------------------------------------------------- scenario
def plot_scenario(scenario, ax=None, *, obstacle_color="0.5", target_color="tab:green",
                  target_alpha: float = 0.35, domain_color="black", start_color="black",
                  start_marker: str = "o", annotate: bool = False, margin: float = 0.02):
    """Draw a scenario: domain outline, grey obstacles, translucent green
    target and the start mean.

    2-D scenarios get equal aspect and limits from the domain's bounding box
    (plus ``margin`` times its largest side); ``annotate=True`` writes each
    obstacle's name at its centroid. 3-D scenarios are drawn on 3-D axes as
    convex-hull facets with an equal box aspect. Returns ``(fig, ax)``.
    """
    dim = scenario.dim
    fig, ax = _axes_for(dim, ax)
    three_d = dim == 3
    _add_polytope(ax, scenario.domain, to_rgba("white", 0.0), domain_color, 1.5 if not three_d else 0.8,
                  "domain", zorder=0.5)
    for ob in scenario.obstacles:
        _add_polytope(ax, ob, to_rgba(obstacle_color, 0.5 if three_d else 1.0), "0.3", 0.8, "obstacle")
        if annotate:
            ax.text(*ob.vertices.mean(axis=0), ob.name, ha="center", va="center", fontsize=7)
    _add_polytope(ax, scenario.target, to_rgba(target_color, target_alpha), target_color, 0.8, "target")
    _plot_polyline(ax, scenario.x0[None], marker=start_marker, color=start_color, markersize=6,
                   linestyle="none", zorder=6, gid="start")

    lo, hi = scenario.domain.bounding_box()
    pad = margin * float(np.max(hi - lo))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if three_d:
        ax.set_zlim(lo[2] - pad, hi[2] + pad)
        ax.set_zlabel("z [m]")
        ax.set_box_aspect(tuple(hi - lo + 2 * pad))
    else:
        ax.set_aspect("equal")
    return fig, ax


# ------------------------------------------------------------ belief path
def plot_belief_path(scenario, path, ax=None, *, prior_color="tab:blue", posterior_color="black",
                     path_color="tab:red", show_prior: bool = True, show_posterior: bool = True,
                     show_scenario: bool = True, linewidth: float = 0.8, title: bool | str | None = None,
                     cost: float | None = None, legend: bool = False):
    """Draw a belief path as in the paper's Figs. 2-3.

    The mean path x_0..x_K as a polyline with a dot per step, the prior
    confidence ellipses E(x_k, P_prior_k) for k = 1..K in ``prior_color`` and
    the posterior ellipses E(x_k, P_k) for k = 0..K in ``posterior_color``,
    both at the scenario's confidence (``scenario.chi2``, 90 % by default).
    Where no measurement is made the two coincide and the posterior is drawn
    on top.

    ``title=True`` writes the scenario name, K and the steering cost
    (``cost`` if given, else ``path.steering_cost(scenario.alpha)``); a string
    is used as the title verbatim. ``show_scenario=False`` draws only the path
    (e.g. on top of :func:`plot_tree`). Returns ``(fig, ax)``.
    """
    if show_scenario:
        fig, ax = plot_scenario(scenario, ax=ax)
    else:
        fig, ax = _axes_for(scenario.dim, ax)
    chi2 = scenario.chi2
    if show_prior:
        plot_ellipses(ax, path.x[1:], path.P_prior[1:], chi2, color=prior_color, linewidth=linewidth,
                      gid="prior-ellipses", zorder=3)
    if show_posterior:
        plot_ellipses(ax, path.x, path.P, chi2, color=posterior_color, linewidth=linewidth,
                      gid="posterior-ellipses", zorder=4)
    _plot_polyline(ax, path.x, color=path_color, linewidth=1.2, marker=".", markersize=4, zorder=5,
                   gid="mean-path")
    if title is True:
        value = path.steering_cost(scenario.alpha) if cost is None else cost
        name = scenario.name or "belief path"
        ax.set_title(f"{name}: K = {path.K}, cost = {value:.4g}")
    elif isinstance(title, str):
        ax.set_title(title)
    if legend:
        pct = f"{100 * scenario.confidence:g} % " if scenario.confidence is not None else ""
        handles = [Line2D([], [], color=path_color, marker=".", label="mean path")]
        if show_prior:
            handles.append(Line2D([], [], color=prior_color, label=f"{pct}prior ellipse"))
        if show_posterior:
            handles.append(Line2D([], [], color=posterior_color, label=f"{pct}posterior ellipse"))
        if show_scenario:
            from matplotlib.patches import Patch

            handles += [Line2D([], [], color="black", marker="o", linestyle="none", label="start"),
                        Patch(facecolor=to_rgba("tab:green", 0.35), edgecolor="tab:green", label="target"),
                        Patch(facecolor="0.5", edgecolor="0.3", label="obstacle")]
        # below the map, outside it, so it never covers the path (nor a neighbouring panel)
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, fontsize=8,
                  frameon=False)
    return fig, ax


# -------------------------------------------------------------------- tree
def plot_tree(scenario, tree, ax=None, *, path=None, edge_color="0.75", linewidth: float = 0.5,
              nodes: bool = False, ellipses: bool = False, path_color="tab:red",
              show_scenario: bool = True):
    """Draw a planner tree over the scenario.

    ``tree`` is any object with ``.x`` (n, d) node means and ``.parent`` (n,)
    parent indices (-1 for a root); edges are one
    :class:`~matplotlib.collections.LineCollection` (gid ``"tree-edges"``,
    n - 1 segments for a tree with one root), so thousands of nodes draw fast.
    ``nodes=True`` adds a dot per node; ``ellipses=True`` draws each node's
    posterior confidence ellipse when the tree has ``.P`` (n, d, d).
    ``path`` (a BeliefPath or an (m, d) array of points) is highlighted as a
    thick polyline; for its ellipses call :func:`plot_belief_path` with
    ``ax=ax, show_scenario=False``. Returns ``(fig, ax)``.
    """
    x = np.asarray(tree.x, dtype=float)
    parent = np.asarray(tree.parent, dtype=int)
    if x.ndim != 2 or parent.shape != (x.shape[0],):
        raise ValueError(f"tree.x must be (n, d) and tree.parent (n,), got {x.shape} and {parent.shape}")
    if np.any(parent < -1) or np.any(parent >= x.shape[0]):
        raise ValueError("tree.parent holds an index out of range")
    if show_scenario:
        fig, ax = plot_scenario(scenario, ax=ax)
    else:
        fig, ax = _axes_for(x.shape[1], ax)

    child = np.flatnonzero(parent >= 0)
    segments = np.stack([x[parent[child]], x[child]], axis=1)
    if _is_3d(ax):
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        edges = Line3DCollection(segments, colors=edge_color, linewidths=linewidth, gid="tree-edges")
        ax.add_collection3d(edges)
    else:
        edges = LineCollection(segments, colors=edge_color, linewidths=linewidth, gid="tree-edges", zorder=2)
        ax.add_collection(edges)
    if nodes:
        _plot_polyline(ax, x, color=edge_color, marker=".", markersize=2, linestyle="none", gid="tree-nodes")
    if ellipses and getattr(tree, "P", None) is not None:
        plot_ellipses(ax, x, np.asarray(tree.P, dtype=float), scenario.chi2, color=edge_color,
                      linewidth=0.4, gid="tree-ellipses", zorder=2)
    if path is not None:
        pts = np.asarray(getattr(path, "x", path), dtype=float)
        _plot_polyline(ax, pts, color=path_color, linewidth=2.0, zorder=5, gid="best-path")
    return fig, ax


# ----------------------------------------------------------- cost curves
def _is_series(obj: Any) -> bool:
    """Whether ``obj`` is one whole cost history (not a single record)."""
    return isinstance(obj, (list, tuple, np.ndarray)) or hasattr(obj, "history") or (
        isinstance(obj, dict) and "history" in obj)


def _cost_series(obj: Any) -> np.ndarray:
    """Costs of one history: numbers, records with a ``cost`` key/attribute,
    or an object (or dict) whose ``history`` holds either."""
    if isinstance(obj, dict) and "history" in obj:
        obj = obj["history"]
    elif not isinstance(obj, (list, tuple, np.ndarray)) and hasattr(obj, "history"):
        obj = obj.history
    costs = []
    for i, rec in enumerate(obj):
        if isinstance(rec, dict):
            if "cost" not in rec:
                raise ValueError(f"history record {i} has no 'cost' key")
            rec = rec["cost"]
        elif hasattr(rec, "cost"):
            rec = rec.cost
        costs.append(float(rec))
    return np.array(costs, dtype=float)


def _labelled_series(histories: Any, labels: Sequence[str] | None) -> list[tuple[str | None, np.ndarray]]:
    if isinstance(histories, dict) and "history" not in histories:
        items = [(str(k), _cost_series(v)) for k, v in histories.items()]
    elif isinstance(histories, np.ndarray) and histories.ndim == 2:
        items = [(None, row.astype(float)) for row in histories]
    elif (isinstance(histories, (list, tuple)) and histories
          and all(_is_series(h) for h in histories)):
        items = [(None, _cost_series(h)) for h in histories]
    else:
        items = [(None, _cost_series(histories))]
    return _relabel(items, labels)


def _relabel(items: list[tuple[str | None, Any]], labels: Sequence[str] | None) -> list[tuple[str | None, Any]]:
    """Replace the labels of (label, data) pairs by ``labels`` when given."""
    if labels is None:
        return items
    labels = list(labels)
    if len(labels) != len(items):
        raise ValueError(f"{len(labels)} labels for {len(items)} curves")
    return [(str(lab), data) for lab, (_, data) in zip(labels, items)]


def plot_cost_history(histories: Any, ax=None, labels: Sequence[str] | None = None, log: bool = False, *,
                      xlabel: str = "CCP iteration", ylabel: str = "steering cost", marker: str = "o"):
    """Cost against CCP iteration for one or several methods (the paper's Fig. 4).

    ``histories`` may be a list of numbers, a list of records (dicts with a
    ``"cost"`` key or objects with a ``cost`` attribute), an object (or dict)
    with a ``history`` of such records, a list of several of these, or a dict
    ``{label: any of these}``. Entry i is drawn at iteration i (entry 0 is
    usually the initial path). ``labels`` names the curves (overriding dict
    keys); ``log=True`` uses a logarithmic cost axis. Non-finite costs leave a
    gap. Returns ``(fig, ax)``.
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 3.8))
    else:
        fig = ax.figure
    items = _labelled_series(histories, labels)
    for label, costs in items:
        costs = np.where(np.isfinite(costs), costs, np.nan)
        ax.plot(np.arange(costs.size), costs, marker=marker, markersize=3, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel if "[" in ylabel else f"{ylabel} [m^2 + alpha nats]")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    if log:
        ax.set_yscale("log")
    _plain_numbers(ax.yaxis)
    ax.grid(True, alpha=0.3)
    if any(label is not None for label, _ in items):
        ax.legend(fontsize=8)
    return fig, ax


def _plain_numbers(axis) -> None:
    """Plain tick labels (2, 3, 4 rather than 2x10^0) on linear and log axes."""
    from matplotlib.ticker import FuncFormatter, LogLocator, ScalarFormatter

    if axis.get_scale() == "log":
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    else:
        fmt = ScalarFormatter(useOffset=False)
        fmt.set_scientific(False)
        axis.set_major_formatter(fmt)


def _runs(obj: Any) -> list[np.ndarray]:
    """One or several best-cost runs as a list of 1-D float arrays."""
    if hasattr(obj, "cost_history"):
        return [np.asarray(obj.cost_history, dtype=float).ravel()]
    try:
        arr = np.asarray(obj, dtype=float)
    except (TypeError, ValueError):  # ragged: runs of different lengths
        return [r for item in obj for r in _runs(item)]
    if arr.ndim == 1:
        return [arr]
    if arr.ndim == 2:
        return list(arr)
    raise ValueError(f"cost history must be 1-D (one run) or 2-D (runs x iterations), got shape {arr.shape}")


def _finite_or_nan(y: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(y), y, np.nan)


def plot_anytime(cost_history: Any, ax=None, *, x: Iterable[float] | None = None,
                 labels: Sequence[str] | None = None, band: bool = True, show_runs: bool | None = None,
                 log: bool = False, xlabel: str = "planner iteration", ylabel: str = "best cost"):
    """Best cost found so far against planner iteration (or node count).

    ``cost_history`` is one run (a sequence of best costs, ``inf`` until the
    first solution; or an object with ``.cost_history``), several runs (a
    list of such sequences or a 2-D array), or a dict ``{label: runs}`` for
    several methods. Infinite entries are not drawn. With several runs the
    median is drawn thick, the individual runs thin (``show_runs``, default
    on) and, with ``band=True``, the band between the lower and upper
    quartiles (order statistics, so runs without a solution count as worst).
    Runs shorter than the longest are extended with their last value (a best
    cost does not change after a run stops). ``x`` gives the abscissae (e.g.
    node counts); the default is iteration 1, 2, ... Returns ``(fig, ax)``.
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 3.8))
    else:
        fig = ax.figure
    if isinstance(cost_history, dict):
        methods = [(str(k), _runs(v)) for k, v in cost_history.items()]
    else:
        methods = [(None, _runs(cost_history))]
    methods = _relabel(methods, labels)

    for label, runs in methods:
        if not runs or max(r.size for r in runs) == 0:
            continue
        n = max(r.size for r in runs)
        R = np.array([np.concatenate([r, np.full(n - r.size, r[-1] if r.size else np.inf)]) for r in runs])
        xs = np.arange(1, n + 1) if x is None else np.asarray(list(x), dtype=float)
        if xs.size < n:
            raise ValueError(f"x has {xs.size} values but a run has {n} entries")
        xs = xs[:n]
        if len(runs) == 1:
            ax.plot(xs, _finite_or_nan(R[0]), linewidth=1.5, label=label)
            continue
        median = np.median(R, axis=0)
        (line,) = ax.plot(xs, _finite_or_nan(median), linewidth=2.0,
                          label=f"{label + ' ' if label else ''}median of {len(runs)} runs")
        color = line.get_color()
        if show_runs is None or show_runs:
            for r in R:
                ax.plot(xs, _finite_or_nan(r), color=color, linewidth=0.6, alpha=0.3)
        if band:
            lower = np.quantile(R, 0.25, axis=0, method="lower")
            upper = np.quantile(R, 0.75, axis=0, method="higher")
            ok = np.isfinite(lower) & np.isfinite(upper)
            ax.fill_between(xs, np.where(ok, lower, np.nan), np.where(ok, upper, np.nan), where=ok,
                            color=color, alpha=0.2, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if log:
        ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    if any(line.get_label() and not line.get_label().startswith("_") for line in ax.get_lines()):
        ax.legend(fontsize=8)
    return fig, ax


# --------------------------------------------------------------- animation
def animate_smoothing(scenario, paths: Sequence, filename: str | Path, fps: float = 4, *, ax=None,
                      titles: Sequence[str] | None = None, dpi: int = 100, close: bool = True,
                      **path_style: Any) -> tuple[Path, FuncAnimation]:
    """Save a GIF of a path evolving over CCP iterations, one frame per path.

    The scenario is drawn once; each frame draws ``paths[i]`` (a
    :class:`~belief_nlp.path.BeliefPath`) with :func:`plot_belief_path`
    (``path_style`` is passed on, e.g. ``prior_color``) under the title
    ``titles[i]`` or "CCP iteration i: cost c" (steering cost at
    ``scenario.alpha``; iteration 0 is the initial path). The title differs
    between frames, so Pillow never merges two frames and the GIF has exactly
    ``len(paths)`` frames. Written with matplotlib's ``PillowWriter`` at
    ``fps`` frames per second; parent folders are created. The figure is
    closed afterwards when this function opened it and ``close`` is true.
    Returns ``(Path(filename), animation)``.
    """
    paths = list(paths)
    if not paths:
        raise ValueError("animate_smoothing needs at least one path")
    if titles is not None and len(titles) != len(paths):
        raise ValueError(f"{len(titles)} titles for {len(paths)} paths")
    own_figure = ax is None
    fig, ax = plot_scenario(scenario, ax=ax)
    background = set(ax.get_children())

    def draw(i: int):
        for artist in [a for a in ax.get_children() if a not in background]:
            artist.remove()
        plot_belief_path(scenario, paths[i], ax=ax, show_scenario=False, **path_style)
        if titles is not None:
            ax.set_title(titles[i])
        else:
            ax.set_title(f"CCP iteration {i}: cost {paths[i].steering_cost(scenario.alpha):.5g}")
        return []

    anim = FuncAnimation(fig, draw, frames=len(paths), blit=False, repeat=False)
    out = Path(filename)
    out.parent.mkdir(parents=True, exist_ok=True)
    anim.save(out, writer=PillowWriter(fps=fps), dpi=dpi)
    if own_figure and close:
        plt.close(fig)
    return out, anim


# -------------------------------------------------------------------- files
def save_figure(fig, filename: str | Path, dpi: int = 150, **savefig_kwargs: Any) -> Path:
    """``fig.savefig`` after creating the parent folders; tight bounding box
    unless ``bbox_inches`` is given. Returns the path written."""
    out = Path(filename)
    out.parent.mkdir(parents=True, exist_ok=True)
    savefig_kwargs.setdefault("bbox_inches", "tight")
    fig.savefig(out, dpi=dpi, **savefig_kwargs)
    return out
