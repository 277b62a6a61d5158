"""Cost against CCP iteration for one or several smoothing runs (the paper's Fig. 4)."""

from __future__ import annotations

from typing import Any, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import MaxNLocator


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
