"""The NLP of a longer horizon read as a shorter one: its first steps frozen.

A receding-horizon loop executes a step and re-plans the K - 1 steps left
(:func:`belief_nlp.replan` with ``advance``). Solved as its own NLP, every
step of the loop is a new horizon: a new graph, new derivatives and a new
solver (~0.5-0.8 s at K = 20), and the last answer's multipliers do not fit
it. The same problem is the K-step NLP with its first ``offset`` steps
frozen at the new start belief (x0, P0), their rows switched off:

- means x_1 .. x_offset = x0 (the control terms of the prefix are 0, and
  ||x_{offset+1} - x_offset||^2 is the first step's);
- sensing and prior information of the prefix chosen so that the posterior
  Y_offset = Q_offset + S_offset is P0^-1 exactly: S_k = 0 ("cholesky") or
  L_k = floor I ("logchol", whose factor cannot be 0) with Q_k = P0^-1 -
  S_k (Q_1 is the NLP's parameter, Q_k for k >= 2 its fixed variable M_k M_k^T);
  the Kalman row of step offset + 1 then gives Q_{offset+1} = (P0 + W)^-1,
  the shorter problem's Q_1, and the start row of transition offset + 1
  (Theorem 1 at x_offset under Y_offset^-1 = P0) is the shorter problem's
  first start row;
- the collision rows of transitions 1 .. offset and the Kalman rows of
  steps 2 .. offset bounded by -inf .. inf (IPOPT keeps such a row free); the
  rows of transition offset + 1 bounded lower by the shorter problem's start
  relief (``Scenario.start_confidence``: what its own NLP adds to them); the
  frozen variables fixed by equal bounds (IPOPT's ``fixed_variable_treatment``
  removes them); the target rows stay: the goal is still reached at step K.

The rest of the NLP is the shorter problem's, term by term (the objective, C5-C8),
up to the constant information of the frozen steps, which ``parts`` takes
off. So the earlier answer's variables and multipliers are a start for the
re-plan on the graph and solver that are already built
(:mod:`belief_nlp.methods.nlp_resume`). Without a risk budget only: a
budget's levels depend on the number of transition-hazard pairs.
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from ..errors import ValidationError
from .data import Layout
from .evaluate import BeliefModel
from .nlp_form import NLPProblem
from .ocp_form import OCPProblem, stage_labels

__all__ = ["frozen", "longer"]


@functools.lru_cache(maxsize=4)
def longer(model: BeliefModel, prefix: int) -> BeliefModel:
    """``model`` with ``prefix`` more steps (its scenario, start and alpha):
    the horizon whose forms a re-plan after ``prefix`` executed steps is
    solved on, with those steps frozen (:func:`frozen`,
    :func:`.conic_prefix.frozen_conic`). Without a risk budget: its levels
    depend on the horizon."""
    if not prefix:
        return model
    if model.risk_budget is not None:
        raise ValidationError("resume", "a re-plan under a risk budget cannot be read on a longer horizon")
    return BeliefModel(model.scenario, model.data.K + prefix, model.data.alpha)


def frozen(nlp: NLPProblem, model: BeliefModel, offset: int) -> NLPProblem:
    """``nlp`` (horizon K, the "cholesky" / "logchol" pair, or fatrop's
    stage-ordered form of one: :func:`_frozen_stages`) with its first
    ``offset`` steps frozen at ``model``'s start belief, read as ``model``'s
    problem (horizon K - offset): its pack, unpack, anchor, bounds, cost
    parts and margins are the shorter problem's; z, p, f and g are ``nlp``'s
    (its solver solves it). Raises ValidationError when the prefix cannot be
    frozen (horizons, a risk budget, or P0^-1 - floor^2 I not positive
    definite for "logchol")."""
    if isinstance(nlp, OCPProblem):
        return _frozen_stages(nlp, model, offset)
    info, D = nlp.info, model.data
    K, d, tri, floor = info["K"], info["d"], info["tri"], info["floor"]
    n = K - offset
    if nlp.formulation not in ("cholesky", "logchol") or not 0 < offset < K or D.K != n \
            or info["n_budget"] or D.budget is not None or D.continuous:
        raise ValidationError("resume", f"a {nlp.formulation!r} NLP of {K} steps cannot be read as {D.K} steps "
                                        f"with {offset} frozen (plain 'cholesky' / 'logchol' NLPs only)")
    t = len(tri)
    P_inv = np.linalg.inv(D.P0)
    L_pre = floor * np.eye(d) if nlp.formulation == "logchol" else np.zeros((d, d))
    Q_pre = 0.5 * (P_inv + P_inv.T) - L_pre @ L_pre.T
    w = np.linalg.eigvalsh(Q_pre)
    if w[0] <= 1e-9 * w[-1]:
        raise ValidationError("resume", "the start covariance is too large to freeze a floored prefix at it")
    start = np.concatenate([D.x0, D.P0.ravel(order="F"), Q_pre.ravel(order="F"),
                            [float(np.linalg.slogdet(Q_pre)[1]), 0.0]])    # (the relief: by the bounds, below)
    # the information of the frozen steps (the model's term at Y_k = P0^-1, Q_k = Q_pre): a constant
    info_pre = offset * float(model.f_step(D.x0, D.x0, P_inv, Q_pre)[1])

    # the frozen variables: those of steps 1..offset (x_k, L_k, M_k, lam_k by the
    # NLP's own step labels), in z's order: the means, the factors L, the M, the certificates
    steps = _steps(nlp)
    idx = np.flatnonzero((steps >= 1) & (steps <= offset))
    ti, tj = [i for i, _ in tri], [j for _, j in tri]
    sens = np.where(np.equal(ti, tj), np.log(floor), 0.0) if nlp.formulation == "logchol" else np.zeros(t)
    vals = np.concatenate([np.tile(D.x0, offset), np.tile(sens, offset),
                           np.tile(np.linalg.cholesky(Q_pre)[ti, tj], offset - 1)])
    vals = np.concatenate([vals, np.zeros(idx.size - vals.size)])           # the certificates: 0
    lbz, ubz = nlp.lbz.copy(), nlp.ubz.copy()
    lbz[idx] = ubz[idx] = vals
    # rows off: collision rows of transitions 1..offset (ordered (k, j, start/end)), Kalman rows of steps 2..offset
    n_col_k = nlp.n_collision // K
    kal0 = nlp.n_collision + info["n_target"]
    off_rows = np.concatenate([np.arange(n_col_k * offset), kal0 + np.arange(t * (offset - 1))]).astype(int)
    lbg, ubg = nlp.lbg.copy(), nlp.ubg.copy()
    lbg[off_rows], ubg[off_rows] = -np.inf, np.inf
    # the shorter problem's transition 1 (the graph's offset + 1) at its start's own level:
    # the relief its own NLP adds to those rows, here taken off their bounds
    first = np.arange(n_col_k * offset, n_col_k * (offset + 1))
    lbg[first] -= D.relief
    keep = np.setdiff1d(np.arange(int(nlp.g.shape[0])), off_rows)

    zs, ps = ca.MX.sym("z", nlp.z.shape[0]), ca.MX.sym("p", nlp.p.shape[0])
    c, i, r = nlp.parts(zs, ps)
    parts = ca.Function("parts", [zs, ps], [c, i - info_pre, r], ["z", "p"], ["control", "information", "regulariser"])

    def extend(lay: Layout) -> Layout:
        return lay.with_prefix(offset, D.x0, Q_pre)

    def pack(lay: Layout) -> np.ndarray:
        zv = nlp.pack(extend(lay))
        zv[idx] = vals
        return zv

    def unpack_with(zv: np.ndarray, model: BeliefModel) -> Layout:
        # Q_1 is the shorter problem's fixed one (what the Kalman row of step offset + 1 holds)
        return nlp.unpack_with(zv, model).tail(offset, model.data.Q1)

    def anchor_with(lay: Layout, alpha: float | None, model: BeliefModel) -> np.ndarray:
        pv = nlp.anchor_with(extend(lay), alpha, model)
        pv[-2 - start.size:-2] = start          # p ends with the start belief, alpha and the switch
        return pv

    return _Frozen(nlp.formulation, nlp.z, nlp.p, nlp.f, nlp.g, lbz, ubz, lbg, ubg, parts, nlp.margins, pack,
                   unpack_with, anchor_with, n_col_k * n, model,
                   # the Kalman rows of steps offset + 1 .. K: the first one holds Q_{offset+1} at (P0 + W)^-1
                   info={**info, "n_kalman": t * n, "frozen": offset}, graph=nlp.graph,
                   source=nlp, offset=offset, start=start, extend=extend, fixed=(idx, vals), relief=D.relief,
                   source_g=lambda gv: np.asarray(gv)[keep])     # the shorter problem's rows, in its order


#: the step of each variable per graph (stage_labels reads the symbols' names:
#: 12 ms at K = 20, 46 ms at K = 80, too much for every re-plan); the
#: "cholesky" / "logchol" pair shares its graph
_STEPS: "weakref.WeakKeyDictionary[ca.Function, np.ndarray]" = weakref.WeakKeyDictionary()


def _steps(nlp: NLPProblem) -> np.ndarray:
    fn = (nlp.graph or {}).get("function")
    if fn is None:
        return stage_labels(nlp)
    if fn not in _STEPS:
        _STEPS[fn] = stage_labels(nlp)
    return _STEPS[fn]


@dataclass
class _Frozen(NLPProblem):
    """:func:`frozen`'s NLP: its start-dependent parts follow the model."""

    source: NLPProblem | None = None
    offset: int = 0
    start: np.ndarray | None = None                       # the start block of p (x0, P0, Q_1, log det Q_1, relief)
    extend: Callable[[Layout], Layout] | None = None      # a shorter point -> the longer NLP's
    fixed: tuple[np.ndarray, np.ndarray] | None = None    # the frozen variables' indices and values
    source_g: Callable[[np.ndarray], np.ndarray] | None = None
    relief: float = 0.0                                   # the shorter problem's start relief (data.relief)

    def margin_values(self, zv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        col, tgt = self.margins(zv, self.start)          # the frozen transitions' rows come first
        col = np.asarray(col, float).ravel()[-self.n_collision:]
        J2 = self.n_collision // self.model.data.K
        col[:J2] += self.relief                          # its transition 1 as its own NLP reads it
        return col, np.asarray(tgt, float).ravel()

    def for_model(self, model: BeliefModel) -> NLPProblem:
        return self if model is self.model else frozen(self.source, model, self.offset)

    def variant(self, formulation: str, floor: float | None = None) -> NLPProblem:
        return frozen(self.source.variant(formulation, floor), self.model, self.offset)

    def without_sensing(self, lay: Layout, floor: float, slack: float = 0.1):
        z0, lbz, ubz = self.source.without_sensing(self.extend(lay), floor, slack)
        idx, vals = self.fixed
        z0[idx] = lbz[idx] = ubz[idx] = vals
        return z0, lbz, ubz


def _frozen_stages(ocp: OCPProblem, model: BeliefModel, offset: int) -> OCPProblem:
    """:func:`frozen` of a stage-ordered form (fatrop's): its source NLP
    frozen, the bounds carried over (the copies stay free: their gap rows
    tie them to the fixed originals; a frozen step's rows are path rows, so
    freeing them keeps the stage structure)."""
    src = frozen(ocp.source, model, offset)
    lbz, ubz, lbg, ubg = ocp.lbz.copy(), ocp.ubz.copy(), ocp.lbg.copy(), ocp.ubg.copy()
    lbz[ocp.orig], ubz[ocp.orig] = src.lbz, src.ubz
    lbg[ocp.source_rows], ubg[ocp.source_rows] = src.lbg, src.ubg
    zs, ps = ca.MX.sym("z", ocp.z.shape[0]), ca.MX.sym("p", ocp.p.shape[0])
    parts = ca.Function("ocp_parts", [zs, ps], list(src.parts(zs[ocp.orig.tolist()], ps)), ["z", "p"],
                        ["control", "information", "regulariser"])
    return _FrozenStages(src, ocp.z, ocp.p, ocp.f, ocp.g, lbz, ubz, lbg, ubg, parts, ocp.margins, ocp.src,
                         ocp.orig, ocp.source_rows, ocp.N, ocp.nx, ocp.nu, ocp.ng,
                         {**ocp.info, "n_kalman": src.info["n_kalman"], "frozen": offset}, ocp.extra,
                         base=ocp, offset=offset)


@dataclass
class _FrozenStages(OCPProblem):
    """:func:`_frozen_stages`' form: its bounds follow the model's start."""

    base: OCPProblem | None = None       # the form of the longer horizon, nothing frozen
    offset: int = 0

    def for_model(self, model: BeliefModel) -> OCPProblem:
        return self if model is self.source.model else frozen(self.base, model, self.offset)

    def source_g(self, gv: np.ndarray) -> np.ndarray:
        # the longer NLP's rows, then the shorter problem's among them, in its order
        return self.source.source_g(super().source_g(gv))
