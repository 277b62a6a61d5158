"""Cost against CCP iteration for one or several smoothing runs (the paper's Fig. 4)."""

from __future__ import annotations

from typing import Any, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import MaxNLocator

from .ticks import plain_numbers

#: Line styles of successive curves (the colours cycle as matplotlib's).
_LINESTYLES = ("-", "--", "-.", ":")


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


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-12, atol=0.0, equal_nan=True))


def _twins(items: list[tuple[str | None, np.ndarray]]) -> list[tuple[str | None, np.ndarray, bool]]:
    """(label, costs, covered) per curve: "(same as X)" added to the label of
    a curve equal to an earlier one, X; ``covered`` when a later curve equals
    this one (it is drawn wide and pale, so the one drawn over it leaves a halo)."""
    out = []
    for j, (label, costs) in enumerate(items):
        twin = next((lab for lab, c in items[:j] if lab is not None and _same(c, costs)), None)
        covered = any(_same(c, costs) for _, c in items[j + 1:])
        out.append((f"{label} (same as {twin})" if label is not None and twin is not None else label, costs, covered))
    return out


def plot_cost_history(histories: Any, ax=None, labels: Sequence[str] | None = None, log: bool = False, *,
                      xlabel: str = "CCP iteration", ylabel: str = "steering cost", marker: str = "o"):
    """Cost against CCP iteration for one or several methods (the paper's Fig. 4).

    ``histories`` may be a list of numbers, a list of records (dicts with a
    ``"cost"`` key or objects with a ``cost`` attribute), an object (or dict)
    with a ``history`` of such records, a list of several of these, or a dict
    ``{label: any of these}``. Entry i is drawn at iteration i (entry 0 is
    usually the initial path). ``labels`` names the curves (overriding dict
    keys); ``log=True`` uses a logarithmic cost axis, labelled at 1-2-5 values
    (denser when the costs span less than a decade, so that at least four
    are labelled). Non-finite costs leave a gap. Successive curves get solid,
    dashed, dash-dot and dotted lines, each drawn over the ones before, so
    curves that coincide (``auto`` and ``ipopt`` when auto's IPOPT stage
    answers) all stay visible: a curve equal to a later one is drawn wide and
    pale beneath it, and the later one is labelled "LABEL (same as EARLIER)".
    Returns ``(fig, ax)``.
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 3.8))
    else:
        fig = ax.figure
    items = _labelled_series(histories, labels)
    # Curves of several methods often coincide (auto's first stage is IPOPT):
    # each gets its own line style, later ones drawn over earlier ones, a
    # curve with a later twin wide and pale beneath it, and the legend names
    # the twin.
    for i, (label, costs, covered) in enumerate(_twins(items)):
        costs = np.where(np.isfinite(costs), costs, np.nan)
        halo = {"linewidth": 4.0, "alpha": 0.45} if covered else {}
        ax.plot(np.arange(costs.size), costs, linestyle=_LINESTYLES[i % len(_LINESTYLES)], marker=marker,
                markersize=3, label=label, zorder=2 + i / max(len(items), 1), **halo)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel if "[" in ylabel else f"{ylabel} [m^2 + alpha nats]")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    if log:
        ax.set_yscale("log")
    plain_numbers(ax.yaxis)
    ax.grid(True, alpha=0.3)
    if any(label is not None for label, _ in items):
        ax.legend(fontsize=8)
    return fig, ax

