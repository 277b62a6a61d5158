"""Cone families: the common currency between the symbolic convex step
(:mod:`.doc`, :mod:`.doc_budget`) and its CVXPY form (:mod:`.cvxpy_form`)."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["ConeFamily", "KINDS"]


KINDS = ("nonneg", "psd", "soc", "exp")


@dataclass(frozen=True)
class ConeFamily:
    """``batch`` cones of one kind. ``expr`` stacks their entries, affine in z:
    psd: the full n x n matrices row-major (n = ``dim``); soc: (t, y) with
    ||y|| <= t (length ``dim``); exp: (a, b, c) with b exp(a / b) <= c; nonneg:
    one entry per cone. ``owner``: per cone, the (transition, hazard) pair it
    belongs to as k * J + j (0-based transition k), -1 for cones of no pair
    (the active-set step, :mod:`.conic_form`, leaves far pairs out). ``step``:
    per cone of no pair, the step k (1..K) of the quantities it constrains
    (sensing, Kalman, log-det cones; a frozen prefix, :mod:`.conic_prefix`,
    leaves those of its steps out), None for the others."""

    name: str
    kind: str
    dim: int
    batch: int
    expr: ca.SX
    owner: np.ndarray | None = None
    step: np.ndarray | None = None


_PADDED: tuple = (None, None)    # (z, vertcat(z, 0)) of the last call: a step's build picks from one z


def _pick(z: ca.SX, idx: np.ndarray) -> ca.SX:
    """Symbolic matrix (idx's 2-D shape) of z entries; 0 where idx < 0 (one
    vectorised selection, no per-entry Python work)."""
    idx = np.atleast_2d(idx)
    n = int(z.numel())
    flat = np.where(idx < 0, n, idx).ravel(order="F")
    global _PADDED
    last, padded = _PADDED           # read once: another thread's build may replace the pair meanwhile
    if last is not z:                # concatenating z anew for each of a build's ~120 picks was 0.06 s
        padded = ca.vertcat(z, 0)
        _PADDED = (z, padded)
    return ca.reshape(padded[flat.tolist()], *idx.shape)
