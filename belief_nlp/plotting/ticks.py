"""Readable cost axes: plain numbers, and log axes with enough labelled ticks.

Matplotlib's default log locator labels decades only, so a cost that falls
from 10 to 2.3 (less than a decade, the usual smoothing curve) shows one or
two labels. :class:`ReadableLogLocator` picks the sparsest 1-2-5 style set
that labels at least four values inside the view.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter, ScalarFormatter

#: Mantissas per decade, sparsest first: the first set that labels at least
#: ``ReadableLogLocator.min_ticks`` values inside the view is used.
_SUBS = ((1.0,), (1.0, 2.0, 5.0), (1.0, 2.0, 3.0, 5.0), (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0))


class ReadableLogLocator(LogLocator):
    """Major ticks of a base-10 log axis with at least ``min_ticks`` inside the view.

    Over many decades it strides over decades as :class:`LogLocator` does;
    within a few decades it adds 2 and 5 (then 3, then 1.5, 4, 6, 8) per
    decade until ``min_ticks`` values fall inside the view; on a view too
    narrow for any of these (e.g. 2.30 to 2.35) it places evenly spaced
    round values as a linear axis would.
    """

    def __init__(self, min_ticks: int = 4, max_ticks: int = 10):
        super().__init__(base=10.0)
        self.min_ticks, self.max_ticks = min_ticks, max_ticks

    def tick_values(self, vmin: float, vmax: float) -> np.ndarray:
        """The major tick values for the view ``[vmin, vmax]``."""
        vmin, vmax = min(vmin, vmax), max(vmin, vmax)
        if not (vmin > 0 and math.isfinite(vmax)):
            return super().tick_values(vmin, vmax)
        lo, hi = math.floor(math.log10(vmin)), math.ceil(math.log10(vmax))
        if hi - lo > self.max_ticks:  # many decades: LogLocator's own stride over decades
            return LogLocator(base=10.0, numticks=self.max_ticks).tick_values(vmin, vmax)
        tol = 1e-9 * (vmax - vmin)
        for subs in _SUBS:
            ticks = np.array([s * 10.0 ** e for e in range(lo, hi + 1) for s in subs])
            inside = ticks[(ticks >= vmin - tol) & (ticks <= vmax + tol)]
            if len(inside) >= self.min_ticks:
                return inside
        return MaxNLocator(nbins=self.min_ticks + 1, steps=[1, 2, 2.5, 5, 10]).tick_values(vmin, vmax)


def plain_numbers(axis) -> None:
    """Plain tick labels (2, 3, 4 rather than 2x10^0) on linear and log axes;
    a log axis gets :class:`ReadableLogLocator` and unlabelled minor ticks."""
    if axis.get_scale() == "log":
        axis.set_major_locator(ReadableLogLocator())
        axis.set_minor_formatter(NullFormatter())
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    else:
        fmt = ScalarFormatter(useOffset=False)
        fmt.set_scientific(False)
        axis.set_major_formatter(fmt)
