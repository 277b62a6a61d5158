"""A belief path: mean polyline with prior and posterior confidence ellipses (the paper's Figs. 2-3)."""

from __future__ import annotations

from matplotlib.colors import to_rgba
from matplotlib.lines import Line2D

from .ellipses import plot_ellipses
from .figure import _axes_for, _plot_polyline
from .scenario import plot_scenario


def plot_belief_path(scenario, path, ax=None, *, prior_color="tab:blue", posterior_color="black",
                     path_color="tab:red", show_prior: bool = True, show_posterior: bool = True,
                     show_scenario: bool = True, linewidth: float = 0.8, title: bool | str | None = None,
                     cost: float | None = None, alpha: float | None = None, legend: bool = False):
    """Draw a belief path as in the paper's Figs. 2-3.

    The mean path x_0..x_K as a polyline with a dot per step, the prior
    confidence ellipses E(x_k, P_prior_k) for k = 1..K in ``prior_color`` and
    the posterior ellipses E(x_k, P_k) for k = 0..K in ``posterior_color``,
    both at the scenario's confidence (``scenario.chi2``, 90 % by default).
    Where no measurement is made the two coincide and the posterior is drawn
    on top.

    ``title=True`` writes the scenario name, K and the steering cost: ``cost``
    if given, else ``path.steering_cost(alpha)``. ``alpha`` is the information
    weight of that cost (not a transparency), by default ``scenario.alpha``;
    pass the alpha the path was smoothed at when it differs from the
    scenario's, and the title then names it ("..., alpha = a"). It only
    affects the title. A string ``title`` is used verbatim.
    ``show_scenario=False`` draws only the path (e.g. on top of
    :func:`plot_tree`). Returns ``(fig, ax)``.
    """
    own_figure = ax is None
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
        weight = scenario.alpha if alpha is None else alpha
        value = path.steering_cost(weight) if cost is None else cost
        name = scenario.name or "belief path"
        at = "" if alpha is None else f", alpha = {float(weight):g}"
        ax.set_title(f"{name}: K = {path.K}, cost = {value:.4g}{at}")
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
        # below the map and its x-axis label, a fixed distance in points (so it clears them on maps of
        # any aspect), never over the path nor a neighbouring panel; the figure's layout makes room for
        # it (a figure of ours: constrained layout; on the caller's axes their layout decides,
        # and tight_layout / constrained layout count the legend too), so a plain savefig keeps it
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3, fontsize=8,
                  frameon=False, borderaxespad=4.0)
        if own_figure and fig.get_layout_engine() is None:
            fig.set_layout_engine("constrained")
    return fig, ax
