"""A scenario: domain outline, obstacles, target and start (polygons in 2-D, hull facets in 3-D)."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import to_rgba
from matplotlib.patches import Polygon

from .figure import _axes_for, _is_3d, _plot_polyline


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
