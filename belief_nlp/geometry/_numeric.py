"""Small numeric helpers shared by the geometry modules."""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

# Tiny isotropic floor added to covariances so that P = 0 (an exact start)
# gives huge-but-finite distances instead of 0/0.
_P_FLOOR = 1e-30


def _quiet(fn: Callable) -> Callable:
    """Run ``fn`` with float warnings off: the vectorised code evaluates
    every branch of its case splits (0/0, inf - inf in unused lanes) and
    selects afterwards. One context per public call is also much cheaper
    than one per helper call."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return fn(*args, **kwargs)
    return wrapper


def _batch(x, P):
    """(n, d) means and (n, d, d) covariances from one ellipse or a batch, and
    whether it was one."""
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    single = x.ndim == 1
    return np.atleast_2d(x), (P[None] if P.ndim == 2 else P), single
