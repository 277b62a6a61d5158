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
  ``"tree-edges"``, ``"tree-nodes"``, ``"tree-ellipses"``, ``"best-path"``,
  ``"risk-ellipses"``, ``"risk-bars"``, ``"risk-budget"``, ``"risk-bound"``.
* 3-D scenarios are drawn on 3-D axes (``mpl_toolkits.mplot3d``): polytopes as
  translucent facets of their convex hulls (``scipy.spatial.ConvexHull``,
  coplanar triangles merged into one polygon per face), confidence ellipsoids
  as coarse translucent meshes. Passing a 2-D axes for a 3-D scenario (or the
  reverse) raises ``ValueError``.
* Open figures are the caller's to close (``plt.close(fig)``), except the one
  :func:`animate_smoothing` opens for itself.

Modules (one idea each; import from ``belief_nlp.plotting``, not from them)
----------------------------------------------------------------------------
* ``figure``: 2-D/3-D axes, :func:`find_artists`, :func:`save_figure`.
* ``ellipses``: :func:`plot_ellipse`, :func:`plot_ellipses` (ellipsoid meshes in 3-D).
* ``scenario``: :func:`plot_scenario` (polytopes, hull facets in 3-D).
* ``belief_path``: :func:`plot_belief_path`.
* ``tree``: :func:`plot_tree`.
* ``cost_history``: :func:`plot_cost_history` (cost against CCP iteration).
* ``anytime``: :func:`plot_anytime` (planner best cost, median and quartiles over runs).
* ``animation``: :func:`animate_smoothing` (GIF over CCP iterations).
* ``ticks``: readable cost axes (plain numbers; log axes with at least four labels).
* ``risk``: :func:`plot_risk_allocation` (ellipses at each transition's own
  level beside the risk allotted per transition), :func:`fixed_allocation`.
"""

from __future__ import annotations

from .animation import animate_smoothing
from .anytime import plot_anytime
from .belief_path import plot_belief_path
from .cost_history import plot_cost_history
from .ellipses import plot_ellipse, plot_ellipses
from .figure import find_artists, save_figure
from .risk import fixed_allocation, plot_risk_allocation
from .scenario import plot_scenario
from .tree import plot_tree

__all__ = [
    "animate_smoothing",
    "find_artists",
    "fixed_allocation",
    "plot_anytime",
    "plot_belief_path",
    "plot_cost_history",
    "plot_ellipse",
    "plot_ellipses",
    "plot_risk_allocation",
    "plot_scenario",
    "plot_tree",
    "save_figure",
]
