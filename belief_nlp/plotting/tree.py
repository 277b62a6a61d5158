"""A planner tree (edges as one line collection) over the scenario."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from .ellipses import plot_ellipses
from .figure import _axes_for, _is_3d, _plot_polyline
from .scenario import plot_scenario


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
