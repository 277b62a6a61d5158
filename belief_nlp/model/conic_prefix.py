"""The CCP step of a longer horizon read as a shorter one: its first steps
frozen (the conic step's counterpart of :mod:`.nlp_prefix`).

After executed steps a re-plan's CCP polish would build the conic step of
the shorter horizon (0.3 s at K = 20, 0.6 s at K = 40: the convex form and
its affine split). The step already built for the longer horizon solves it
with the prefix frozen at the new start belief (x0, P0), as the active-set
step already holds far pairs:

- the prefix's means (dx = 0 at x0), sensing (S = 0), prior information
  (Q = P0^-1, Q_1 through the step's start parameter) and log-det
  auxiliaries are held at those values, and their cones (sensing, Kalman,
  log-det; :attr:`.cones.ConeFamily.step`) and their pairs' cones left out;
- the Kalman LMI of step offset + 1 then bounds Q_{offset+1} by
  (P0 + W)^-1, the shorter step's Q_1, and the start end of transition
  offset + 1 sees Y_offset = P0^-1 (C7). The shorter step holds that end
  exactly (C8); here it is a generic pair, whose majorant's split term also
  weighs the certificates' change: a majorant tight at the point all the
  same, so each step is safe and monotone and CCP's fixed points are the
  shorter step's, but a step's answer differs a little (means within 1e-5
  relative in the tests);
- the prefix's objective terms are constants;
- a start held to its own level (``Scenario.start_confidence``) puts its
  relief on the step's level parameter of transition offset + 1.

Not under a risk budget or the continuous-time surrogate (their levels and
T_k depend on the horizon). ``tests/test_receding.py`` holds its answer to
the shorter horizon's own step.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import ValidationError
from .conic_form import ConicStep
from .data import Layout, ProblemData
from .doc import StepLayout, step_start_values

__all__ = ["frozen_conic", "FrozenConic"]


@dataclass
class _FrozenStart(StepLayout):
    """The longer step's layout with the frozen prefix's start parameters."""

    start: np.ndarray | None = None
    alpha: float = 1.0

    def params(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray) -> np.ndarray:
        pv = StepLayout.params(self, point, rho_start, rho_end)
        pv[-1 - self.start.size:-1] = self.start
        pv[-1] = self.alpha
        return pv


@dataclass
class _ShortLayout:
    """What a CCP run reads of a step's layout, for the shorter problem:
    its data, the longer step's variables (``blocks``) and :meth:`extract`."""

    data: ProblemData
    blocks: object
    source: StepLayout
    offset: int
    P_inv: np.ndarray

    def extend(self, point: Layout) -> Layout:
        """The longer step's point: the frozen prefix, then ``point``."""
        return point.with_prefix(self.offset, self.data.x0, self.P_inv)

    def extract(self, zv: np.ndarray, point: Layout) -> Layout:
        """The shorter problem's new point from the longer step's answer."""
        return self.source.extract(zv, self.extend(point)).tail(self.offset, self.data.Q1)


@dataclass
class FrozenConic:
    """The longer conic step as the shorter problem's (:meth:`solve` as
    :meth:`ConicStep.solve`, its answers in the longer step's z: read them
    with ``layout.extract``)."""

    step: ConicStep
    layout: _ShortLayout
    frozen: tuple[np.ndarray, np.ndarray]        # (variables, cones) of the prefix

    def solve(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray, keep: np.ndarray,
              settings: dict | None = None,
              time_left: float | None = None) -> tuple[str, np.ndarray | None, float, int]:
        off, J = self.layout.offset, self.layout.data.J
        pad = np.ones((off, J))
        keep = np.concatenate([np.zeros(off * J, bool), np.asarray(keep, bool).ravel()])
        return self.step.solve(self.layout.extend(point), np.vstack([pad, rho_start]), np.vstack([pad, rho_end]),
                               keep, settings, time_left, frozen=self.frozen)


def frozen_conic(step: ConicStep, D: ProblemData, offset: int) -> FrozenConic:
    """``step`` (horizon K) with its first ``offset`` steps frozen at ``D``'s
    start belief, as the step of ``D`` (horizon K - offset). Raises
    ValidationError when it cannot be (horizons, a risk budget, the
    continuous-time surrogate)."""
    L = step.layout
    Dt, B = L.data, L.blocks
    K = Dt.K
    if not 0 < offset < K or D.K != K - offset or B.ell is not None or D.budget is not None \
            or Dt.continuous or D.continuous:
        raise ValidationError("resume", f"a conic step of {K} steps cannot be read as {D.K} steps with {offset} "
                                        f"frozen (plain steps only)")
    P_inv = np.linalg.inv(D.P0)
    P_inv = 0.5 * (P_inv + P_inv.T)
    cols = np.zeros(B.n, bool)
    for imap in (B.x[1:offset + 1], B.Q[2:offset + 1], B.S[1:offset + 1], B.Z[2:offset + 1], B.u[2:offset + 1]):
        cols[imap[imap >= 0]] = True
    cone_step = step.cones[5]
    cones = (cone_step >= 1) & (cone_step <= offset)
    # the shorter problem's start relief at its transition 1, the step's offset + 1
    start = step_start_values(D, K, at=offset)
    start[D.d:D.d + D.d * D.d] = P_inv.ravel(order="F")      # Q_1 = P0^-1: the prefix sees the start belief
    solver_step = replace(step, layout=_FrozenStart(Dt, B, start, D.alpha))
    return FrozenConic(solver_step, _ShortLayout(D, B, L, offset, P_inv), (cols, cones))
