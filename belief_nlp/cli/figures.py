"""Figure helpers shared by the subcommands: off-screen drawing, side-by-side
scenario panels, saving into the output folder."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Iterable

from .common import _Run, iterates_feasible


def _headless_matplotlib() -> None:
    """Draw off-screen unless the caller (a notebook, a script) already chose."""
    if "matplotlib.pyplot" not in sys.modules and not os.environ.get("MPLBACKEND"):
        import matplotlib

        matplotlib.use("Agg")


def _save_and_close(fig, file: Path, **kwargs) -> Path:
    """Save ``fig`` (creating folders; see plotting.save_figure) and close it."""
    import matplotlib.pyplot as plt

    from ..plotting import save_figure

    try:
        return save_figure(fig, file, **kwargs)
    finally:
        plt.close(fig)


def _save_fig(run: _Run, fig, name: str) -> Path:
    """Save ``fig`` as OUT/name at the run's --dpi, record it, close it."""
    return run.wrote(_save_and_close(fig, run.out / name, dpi=run.args.dpi))


def _panels(n: int, dim: int, size: float = 4.6):
    """A figure with n scenario panels side by side (3-D axes for 3-D scenarios)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(size * n, size))
    kw = {"projection": "3d"} if dim == 3 else {}
    return fig, [fig.add_subplot(1, n, i + 1, **kw) for i in range(n)]


def _no_path_panel(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9, color="tab:red",
            zorder=20, bbox={"facecolor": "white", "edgecolor": "tab:red", "alpha": 0.85})


def _plotted_costs(method: str, history: Iterable[tuple[float | None, bool]]) -> list[float]:
    """The finite costs of (cost, accepted) pairs that a cost plot shows: the
    accepted iterates of a method whose iterates are all feasible (CCP: a
    rejected step is not part of the run), else every iterate (IPOPT)."""
    keep_all = not iterates_feasible(method)
    return [c for c, accepted in history if (keep_all or accepted) and c is not None and math.isfinite(c)]
