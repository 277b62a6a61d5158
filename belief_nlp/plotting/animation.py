"""A GIF of a belief path evolving over CCP iterations (the paper's videos)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib.pyplot as plt
from matplotlib.animation import FuncAnimation, PillowWriter

from .belief_path import plot_belief_path
from .scenario import plot_scenario


def animate_smoothing(scenario, paths: Sequence, filename: str | Path, fps: float = 4, *, ax=None,
                      titles: Sequence[str] | None = None, dpi: int = 100, close: bool = True,
                      **path_style: Any) -> tuple[Path, FuncAnimation]:
    """Save a GIF of a path evolving over CCP iterations, one frame per path.

    The scenario is drawn once; each frame draws ``paths[i]`` (a
    :class:`~belief_nlp.path.BeliefPath`) with :func:`plot_belief_path`
    (``path_style`` is passed on, e.g. ``prior_color``) under the title
    ``titles[i]`` or "CCP iteration i: cost c" (steering cost at
    ``path_style["alpha"]`` if given, else ``scenario.alpha``; iteration 0 is
    the initial path). The title differs
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
    alpha = scenario.alpha if path_style.get("alpha") is None else path_style["alpha"]

    def draw(i: int):
        for artist in [a for a in ax.get_children() if a not in background]:
            artist.remove()
        plot_belief_path(scenario, paths[i], ax=ax, show_scenario=False, **path_style)
        if titles is not None:
            ax.set_title(titles[i])
        else:
            ax.set_title(f"CCP iteration {i}: cost {paths[i].steering_cost(alpha):.5g}")
        return []

    anim = FuncAnimation(fig, draw, frames=len(paths), blit=False, repeat=False)
    out = Path(filename)
    out.parent.mkdir(parents=True, exist_ok=True)
    anim.save(out, writer=PillowWriter(fps=fps), dpi=dpi)
    if own_figure and close:
        plt.close(fig)
    return out, anim
