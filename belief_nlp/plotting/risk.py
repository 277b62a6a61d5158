"""How a path spends its collision-probability budget: each transition's
ellipse at its own confidence level beside the risk allotted per transition
(issue 20, item 4)."""

from __future__ import annotations

from typing import Any, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LogNorm, Normalize
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..allocation import RiskAllocation
from ..errors import ValidationError
from ..path import BeliefPath
from ..risk import path_risk
from ..scenario import Scenario, load_scenario
from .ellipses import _ellipse_patch, _ellipsoid_quads
from .figure import _is_3d, _plot_polyline
from .scenario import plot_scenario

BAR_STYLES = ("dominant", "stacked")
# Below this fraction of the largest transition's risk, colours saturate: a
# transition far from every hazard carries ~1e-15 and would otherwise stretch
# the colour scale over irrelevant decades.
_COLOUR_DECADES = 1e-6


def plot_risk_allocation(scenario: Scenario | str, result_or_path: Any, allocation: RiskAllocation | None = None,
                         ax: Sequence | None = None, *, log: bool = False, bars: str = "dominant",
                         cmap: str = "plasma", reference: bool = True, title: bool | str = True):
    """The smoothed path with each transition's ellipse at its own level, and
    the risk allotted to each transition as bars.

    Left panel: the scenario, the mean path and one confidence ellipse per
    step. The posterior at step k (k = 1..K) is drawn at transition k's
    level tau_k = min_j levels[k-1, j], the smallest level over its hazards
    -- which is the level of the pair that carries most of the transition's
    risk (g is decreasing), the active pair of an optimal allocation -- and
    the start's posterior P_0 at tau_1, the level of the transition that
    begins there: K + 1 ellipses (gid ``"risk-ellipses"``). Each is
    coloured by the risk allotted to its transition (sum over hazards, a
    logarithmic colour bar). With ``reference=True`` the posteriors are also
    drawn thin and dashed at the scenario's fixed ``chi2`` (gid
    ``"posterior-ellipses"``), the paper's single level, for comparison.

    Right panel: one bar per transition k = 1..K (gids ``"risk-bars"``),
    either its allotted risk coloured by the hazard carrying most of it
    (``bars="dominant"``) or stacked per hazard (``bars="stacked"``, linear
    axis only: on a log axis the lowest segment would fill the bar); either
    way the bar heights add up to ``allocation.allotted``. Horizontal lines
    mark the end-to-end budget (gid ``"risk-budget"``, when finite) and the
    certified bound of the path (gid ``"risk-bound"``); the title states
    both with the allotted sum.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario (or a built-in name / scenario file); its hazards
        (obstacles, then domain walls) are the allocation's columns.
    result_or_path : SmoothResult, BeliefPath or object with ``.path``
        A smoothing result (its ``path``, its ``risk`` and its
        ``certificates`` are used) or a belief path.
    allocation : RiskAllocation, optional
        The allocation to draw; overrides ``result.risk``. Without one (a
        plain path, or a result smoothed at a fixed level) the path's own
        certified bounds are drawn as a "fixed" allocation
        (:func:`fixed_allocation`), so any path can be plotted.
    ax : pair of Axes, optional
        ``(map_axes, bar_axes)`` to draw on (3-D map axes for a 3-D
        scenario); None opens a new figure with both panels.
    log : bool, optional
        Logarithmic risk axis for the bars (risks span many decades).
    bars : {"dominant", "stacked"}, optional
        How the bars show the hazards (above); "stacked" needs ``log=False``.
    cmap : str, optional
        Colour map of the ellipses.
    reference : bool, optional
        Also draw the posteriors at the scenario's fixed level.
    title : bool or str, optional
        True: the scenario's name on the map and the risk totals on the bars;
        a string titles the figure; False: no titles.

    Returns
    -------
    fig : matplotlib.figure.Figure
    axes : tuple of Axes
        ``(map_axes, bar_axes)``.

    Raises
    ------
    ValidationError
        When an argument is of the wrong kind, or the allocation's arrays do
        not have shape (K, J) for the path's K transitions and the scenario's
        J hazards, or when the allocation holds negative or non-finite risks;
        the error names the argument.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if not isinstance(sc, Scenario):
        raise ValidationError("scenario", f"must be a Scenario or a scenario name, got {type(sc).__name__}")
    path = getattr(result_or_path, "path", result_or_path)
    if not isinstance(path, BeliefPath):
        raise ValidationError("result_or_path", f"must be a BeliefPath or a result holding one in .path, got "
                                                f"{type(result_or_path).__name__}")
    if path.dim != sc.dim:
        raise ValidationError("result_or_path", f"path is {path.dim}-D but the scenario is {sc.dim}-D")
    if bars not in BAR_STYLES:
        raise ValidationError("bars", f"must be one of {BAR_STYLES}, got {bars!r:.40}")
    if bars == "stacked" and log:
        raise ValidationError("bars", "stacked bars need a linear axis (log=False): on a logarithmic axis the "
                                      "lowest segment fills the bar; use bars='dominant' with log=True")
    if allocation is None:
        allocation = getattr(result_or_path, "risk", None)
    if allocation is None:
        allocation = fixed_allocation(sc, path, getattr(result_or_path, "certificates", None))
    risk, levels = _checked(allocation, path.K, len(sc.hazards))
    fig, ax_map, ax_bar = _two_panels(sc.dim, ax)

    per_k = risk.sum(axis=1)
    colours, mappable = _colours(per_k, cmap)
    tau = levels.min(axis=1)                                             # transition k's level
    tau = np.where(np.isfinite(tau), np.maximum(tau, 0.0), 0.0)         # no claim: a point, not a plane
    step_tau = np.concatenate([tau[:1], tau])                            # the start takes transition 1's
    step_col = np.concatenate([colours[:1], colours])
    plot_scenario(sc, ax=ax_map)
    if reference:
        _ellipses(ax_map, path.x, path.P, np.full(path.K + 1, sc.chi2), ["0.55"] * (path.K + 1),
                  "posterior-ellipses", linestyle="--", linewidth=0.5, zorder=3)
    _ellipses(ax_map, path.x, path.P, step_tau, step_col, "risk-ellipses", linewidth=1.1, zorder=4)
    _plot_polyline(ax_map, path.x, color="black", linewidth=1.0, marker=".", markersize=4, zorder=5,
                   gid="mean-path")
    fig.colorbar(mappable, ax=ax_map, shrink=0.8, label="risk allotted to the transition")

    names = list(allocation.hazard_names) or [h.name for h in sc.hazards]
    handles, legend_title = _bars(ax_bar, risk, names, bars)
    handles += _totals(ax_bar, allocation, log)
    ax_bar.legend(handles=handles, title=legend_title, fontsize=7, title_fontsize=7, loc="upper left",
                  bbox_to_anchor=(1.0, 1.0), frameon=False)
    if title is True:
        ax_map.set_title(f"{sc.name or 'path'}: K = {path.K}, ellipse k at its own level")
        budget = (f"budget {allocation.budget:.3g}" if np.isfinite(allocation.budget)
                  else "no budget")
        ax_bar.set_title(f"{allocation.method}: allotted {risk.sum():.3g}, certified {allocation.bound:.3g}, "
                         f"{budget}", fontsize=10)
    elif isinstance(title, str):
        fig.suptitle(title)
    return fig, (ax_map, ax_bar)


def fixed_allocation(scenario: Scenario, path: BeliefPath, certificates: np.ndarray | None = None) -> RiskAllocation:
    """The allocation a path at fixed levels spends: its certified bounds.

    Each pair's level is its certified squared Mahalanobis clearance and its
    risk the instantaneous bound g(clearance) (:func:`belief_nlp.risk.path_risk`),
    the bound the Boole sum ``step_time``; ``method`` is ``"fixed"`` and
    ``budget`` NaN (none was given).

    Parameters
    ----------
    scenario : Scenario
        The path's scenario.
    path : BeliefPath
        Any path.
    certificates : ndarray, shape (K, J, F), optional
        Theorem-1 certificates (``SmoothResult.certificates``), which may
        raise the clearances.

    Returns
    -------
    RiskAllocation
    """
    rb = path_risk(scenario, path, certificates)
    return RiskAllocation(budget=float("nan"), allocation=np.asarray(rb.pairs, float),
                          levels=np.asarray(rb.clearance, float), bound=rb.step_time, method="fixed",
                          hazard_names=tuple(rb.hazard_names))


def _checked(allocation: Any, K: int, J: int) -> tuple[np.ndarray, np.ndarray]:
    """The allocation's (K, J) risk and level arrays, checked against the path and scenario."""
    if not isinstance(allocation, RiskAllocation):
        raise ValidationError("allocation", f"must be a RiskAllocation, got {type(allocation).__name__}")
    out = []
    for name in ("allocation", "levels"):
        a = np.asarray(getattr(allocation, name), dtype=float)
        if a.shape != (K, J):
            raise ValidationError("allocation", f"allocation.{name} has shape {a.shape}, but the path has K = {K} "
                                                f"transitions and the scenario J = {J} hazards: need ({K}, {J})")
        out.append(a)
    risk, levels = out
    if not np.all(np.isfinite(risk)) or np.any(risk < 0):
        raise ValidationError("allocation", "allocation.allocation must hold finite probabilities >= 0")
    return risk, levels


def _two_panels(dim: int, ax: Sequence | None):
    """(fig, map axes, bar axes): the caller's pair, checked, or a new figure."""
    if ax is None:
        fig = plt.figure(figsize=(11.5, 5.0), layout="constrained")
        ax_map = fig.add_subplot(1, 2, 1, projection="3d" if dim == 3 else None)
        return fig, ax_map, fig.add_subplot(1, 2, 2)
    try:
        ax_map, ax_bar = ax
    except (TypeError, ValueError):
        raise ValidationError("ax", "must be a pair (map axes, bar axes)") from None
    if (dim == 3) != _is_3d(ax_map):
        raise ValidationError("ax", f"the map of a {dim}-D scenario needs {'3-D' if dim == 3 else '2-D'} axes")
    if _is_3d(ax_bar):
        raise ValidationError("ax", "the bars need 2-D axes")
    return ax_map.figure, ax_map, ax_bar


def _colours(per_k: np.ndarray, cmap: str) -> tuple[np.ndarray, ScalarMappable]:
    """RGBA per transition on a logarithmic scale of its risk, and the mappable for a colour bar."""
    top = float(per_k.max(initial=0.0))
    if top > 0:
        low = max(float(per_k[per_k > 0].min()), _COLOUR_DECADES * top)
        norm = LogNorm(vmin=min(low, top / 10), vmax=top, clip=True)
    else:
        norm = Normalize(0.0, 1.0)
    mappable = ScalarMappable(norm=norm, cmap=plt.get_cmap(cmap))
    values = np.where(per_k > 0, per_k, norm.vmin)                   # zero risk: the scale's low end
    return mappable.to_rgba(values), mappable


def _ellipses(ax, xs: np.ndarray, Ps: np.ndarray, levels: np.ndarray, colours, gid: str, **style: Any):
    """One ellipse (2-D) or ellipsoid mesh (3-D) per row, each at its own level and colour, as one collection."""
    if _is_3d(ax):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        quads = [_ellipsoid_quads(x, P, t) for x, P, t in zip(xs, Ps, levels)]
        face = np.repeat(np.asarray([plt.matplotlib.colors.to_rgba(c) for c in colours]), [len(q) for q in quads],
                         axis=0)
        face[:, 3] = 0.15
        coll = Poly3DCollection(np.concatenate(quads), facecolors=face, edgecolor="none")
        coll.set_gid(gid)
        ax.add_collection3d(coll)
        return coll
    from matplotlib.collections import PatchCollection

    coll = PatchCollection([_ellipse_patch(x, P, t) for x, P, t in zip(xs, Ps, levels)], facecolor="none",
                           edgecolor=list(colours), **style)
    coll.set_gid(gid)
    ax.add_collection(coll)
    return coll


def _hazard_colours(n: int) -> list:
    """A distinct colour per hazard (tab10, then tab20b beyond ten hazards)."""
    base = list(plt.get_cmap("tab10").colors) + list(plt.get_cmap("tab20b").colors)
    return [base[j % len(base)] for j in range(n)]


def _bars(ax, risk: np.ndarray, names: list[str], style: str) -> tuple[list, str]:
    """Bars of the risk per transition (see :func:`plot_risk_allocation`); every
    rectangle has gid "risk-bars". Returns the legend's hazard entries and its title."""
    K, J = risk.shape
    k = np.arange(1, K + 1)
    palette = _hazard_colours(J)
    if style == "dominant":
        top = np.argmax(risk, axis=1)
        patches = list(ax.bar(k, risk.sum(axis=1), color=[palette[j] for j in top], edgecolor="0.2",
                              linewidth=0.4))
        shown = sorted(set(top[risk.sum(axis=1) > 0].tolist()))
        title = "hazard carrying most"
    else:
        bottom = np.zeros(K)
        patches = []
        for j in range(J):
            patches += list(ax.bar(k, risk[:, j], bottom=bottom, color=palette[j], linewidth=0))
            bottom = bottom + risk[:, j]
        # hazards with a visible share of the total go in the legend
        shown = [j for j in range(J) if risk[:, j].sum() > 1e-3 * max(risk.sum(), 1e-300)]
        title = "hazard"
    for p in patches:
        p.set_gid("risk-bars")
    ax.set_xlabel("transition k")
    ax.set_ylabel("allotted collision probability")
    ax.set_xticks(k if K <= 12 else k[k % int(np.ceil(K / 10)) == 0])      # labels that do not overlap
    ax.set_xlim(0.4, K + 0.6)
    return [Patch(facecolor=palette[j], label=names[j]) for j in shown], title


def _totals(ax, allocation: RiskAllocation, log: bool) -> list:
    """Lines for the end-to-end budget and certified bound, and the risk axis's
    scale. Returns the lines' legend entries."""
    heights = [p.get_y() + p.get_height() for p in ax.patches if p.get_gid() == "risk-bars"]
    budget = float(allocation.budget)
    top = max([h for h in heights if h > 0] + [float(allocation.bound)]
              + ([budget] if np.isfinite(budget) else []) + [1e-300])
    handles = []
    if np.isfinite(budget):
        ax.axhline(budget, color="tab:red", linestyle="--", linewidth=1.0, gid="risk-budget")
        handles.append(Line2D([], [], color="tab:red", linestyle="--", label=f"budget {budget:.3g} (end to end)"))
    ax.axhline(allocation.bound, color="black", linestyle=":", linewidth=1.0, gid="risk-bound")
    handles.append(Line2D([], [], color="black", linestyle=":",
                          label=f"certified bound {allocation.bound:.3g} (end to end)"))
    if log:
        ax.set_yscale("log")
        positive = [h for h in heights if h > 0]
        low = max(min(positive, default=top * 1e-6), top * 1e-8)
        ax.set_ylim(low / 2, top * 2)
    else:
        ax.set_ylim(0, 1.1 * top)
    ax.grid(True, axis="y", alpha=0.3)
    return handles
