"""Axes and figure plumbing shared by every plot: 2-D/3-D axes, artists by gid, saving."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np


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
    """All artists of ``ax`` whose ``gid`` is ``gid`` (gids: see :mod:`belief_nlp.plotting`)."""
    return [a for a in ax.get_children() if a.get_gid() == gid]


def _plot_polyline(ax, pts: np.ndarray, **style: Any):
    """ax.plot for (n, 2) or (n, 3) points; returns the Line2D."""
    pts = np.asarray(pts, dtype=float)
    (line,) = ax.plot(*pts.T, **style)
    return line


def save_figure(fig, filename: str | Path, dpi: int = 150, **savefig_kwargs: Any) -> Path:
    """``fig.savefig`` after creating the parent folders; tight bounding box
    unless ``bbox_inches`` is given. Returns the path written."""
    out = Path(filename)
    out.parent.mkdir(parents=True, exist_ok=True)
    savefig_kwargs.setdefault("bbox_inches", "tight")
    fig.savefig(out, dpi=dpi, **savefig_kwargs)
    return out
