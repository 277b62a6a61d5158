"""Anytime curves: a planner's best cost so far against iteration, median and quartiles over runs."""

from __future__ import annotations

from typing import Any, Iterable, Sequence

import matplotlib.pyplot as plt
import numpy as np

from .cost_history import _relabel
from .ticks import plain_numbers


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
        plain_numbers(ax.yaxis)
    ax.grid(True, alpha=0.3)
    if any(line.get_label() and not line.get_label().startswith("_") for line in ax.get_lines()):
        ax.legend(fontsize=8)
    return fig, ax
