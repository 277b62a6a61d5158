"""The exact DOC program as one NLP for CasADi's ``nlpsol`` (IPOPT and the other
NLP solvers), built from the model's terms (:class:`~belief_nlp.model.BeliefModel`
functions over :mod:`.terms`); this module only chooses the variables.

Variables, k = 1..K (scaled units): means x_k; sensing S_k = L_k L_k^T (L_k
lower triangular: every L gives S >= 0 and S = 0 is the smooth point L = 0);
prior information Q_k = M_k M_k^T for k >= 2 (diag M_k >= 1e-8, so
log det Q_k = 2 sum log M_k,ii), tied to the previous step by the Kalman
equality (Lemma 2); Q_1 = (P0 + W)^-1 fixed (C8); one certificate
lam_kj >= 0 per transition and hazard (Theorem 1, C5), real faces only.

    min  sigma^2 sum_k ||x_k - x_{k-1}||^2 + alpha/2 sum_k (log det Y_k - log det Q_k)
         + eps/2 ||lam - lam_0||^2
    s.t. kalman_residual(Q_k, Y_{k-1}) = 0                         k >= 2
         collision_margin_cov(x_0, P0, lam_1j)        >= m         k = 1 start (C8)
         collision_margin_inv(x_{k-1}, Y_{k-1}, lam_kj) >= m       k >= 2 start
         collision_margin_inv(x_k, Q_k, lam_kj)        >= m        every end
         target_margin(x_K, Y_K, a_n, b_n)             >= m'       (C4)

with m = margin chi2 and m' = margin (scaled length). Under a risk budget
(``data.budget``, :mod:`belief_nlp.allocation`) each pair's level is a
variable tau_kj in [tau_lo, tau_hi]: its rows ask for tau_kj (1 + margin)
instead of chi2 + m, and one more row keeps sum_kj g(tau_kj) <= budget with
g(tau) = Phi_bar(sqrt(tau)) exactly. Under a continuous-time budget
(``data.continuous``) both ends of transition k use the information
T_k = (Q_{k-1}^-1 + W)^-1 (T_1 = Q_1) instead. Why these choices and
the measured alternatives ("minors", "eliminated"): docs/numerics.md, "IPOPT".
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cached_property
from itertools import combinations
from typing import Callable

import casadi as ca
import numpy as np

from ..errors import ValidationError
from . import terms
from .data import Layout, ProblemData
from .evaluate import BeliefModel
from .nlp_matrices import _lower, _psd_factor, _sym_inv, _symmetric, _tri_index, lower_stack, switched_off

__all__ = ["NLPProblem", "build_nlp", "FORMULATIONS"]

FORMULATIONS = ("cholesky", "logchol", "minors", "eliminated")


@dataclass
class NLPProblem:
    """The smoothing problem as one CasADi NLP (scaled units of model.py).

    Attributes
    ----------
    z, p, f, g : CasADi SX decision vector, parameter (the certificates lam_0
        of the proximal term, alpha, and the switch of the "cholesky" /
        "logchol" pair), objective and constraints (both read p: evaluate them
        at ``anchor(point)``). alpha and the switch are parameters, not
        constants, so that one solver serves every alpha of a (scenario, K)
        and both NLP stages share one graph and its derivatives (their
        construction is most of a first call: docs/numerics.md, "Construction cost").
    lbz, ubz, lbg, ubg : bounds (numpy).
    parts : Function (z, p) -> (control [m^2], information [nats], regulariser).
    margins : Function (z, start) -> (collision margins (2 K J,), target
        margins (N,)), start the start belief's parameters
        (:func:`start_values`; :meth:`margin_values` passes the model's);
        collision margins are the certificate values
        -v^T P v + 2 lam^T (A x - b) - chi2 (a lower bound on the squared
        Mahalanobis clearance minus chi2), ordered (k, j, start/end).
    pack : Layout -> z values; unpack_with : (z values, model) -> Layout (S
        from its factor; Q as the variables say -- use model.tighten for the
        Kalman one); :meth:`unpack` with this NLP's ``model``.
    anchor_with : (Layout, alpha or None, model) -> p values (the point's
        certificates, the model's start belief and alpha; None: the model's);
        :meth:`anchor` with this NLP's ``model``.
    model : the model whose data the numeric parts read: only its start
        belief (x0, P0) and alpha may differ from the model the graph was
        built from, both are parameters (:meth:`for_model`).
    n_collision : number of collision rows at the start of g.
    graph : the symbolic part (a CasADi function of (z, p) and the row
        counts) that rebuilds this NLP's expressions: ``build_nlp(...,
        graph=)``; what the disk cache keeps.
    """

    formulation: str
    z: ca.SX
    p: ca.SX
    f: ca.SX
    g: ca.SX
    lbz: np.ndarray
    ubz: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    parts: ca.Function
    margins: ca.Function
    pack: Callable[[Layout], np.ndarray]
    unpack_with: Callable[[np.ndarray, BeliefModel], Layout]
    anchor_with: Callable[..., np.ndarray]
    n_collision: int
    model: BeliefModel
    info: dict = field(default_factory=dict)
    _view: Callable[[str, float], "NLPProblem"] | None = field(default=None, repr=False)
    graph: dict | None = field(default=None, repr=False)

    @cached_property
    def fg(self) -> ca.Function:
        """(z, p) -> (f, g): the objective and the rows as one function (built
        on first use; the recorder's values for solvers that pass none, the
        disk cache's hash of the graph)."""
        return ca.Function("belief_nlp_fg", [self.z, self.p], [self.f, self.g])

    def unpack(self, zv: np.ndarray) -> Layout:
        """z values -> Layout, with this NLP's model's start belief."""
        return self.unpack_with(zv, self.model)

    def anchor(self, lay: Layout, alpha: float | None = None) -> np.ndarray:
        """p values at ``lay``: its certificates (the proximal term's centre),
        the model's start belief and alpha (None: the model's), the switch."""
        return self.anchor_with(lay, alpha, self.model)

    def margin_values(self, zv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(collision, target) margins at z values, with the model's start belief."""
        col, tgt = self.margins(zv, start_values(self.model.data))
        return np.asarray(col, float).ravel(), np.asarray(tgt, float).ravel()

    def for_model(self, model: BeliefModel) -> "NLPProblem":
        """This NLP (the same graph, bounds and solver-facing parts) reading
        ``model``'s start belief and alpha: a model whose data differ only in
        those (the memory cache's key leaves them out, :func:`.cache.problem_key`)."""
        if model is self.model:
            return self
        out = copy.copy(self)        # keeps a form's own attributes (nlp_scaled's without_sensing)
        out.model = model
        return out

    def variant(self, formulation: str, floor: float | None = None) -> "NLPProblem":
        """The other member of the "cholesky" / "logchol" pair on the same
        expression graph (the same z, p, f, g objects: a solver's derivative
        functions serve both); its own bounds, packing and parameter value.
        ``floor`` defaults to this one's."""
        if self._view is None or formulation not in ("cholesky", "logchol"):
            raise ValidationError("formulation", f"the {self.formulation!r} NLP has no {formulation!r} variant "
                                                 f"(only 'cholesky' and 'logchol' share one graph)")
        return self._view(formulation, self.info["floor"] if floor is None else float(floor)).for_model(self.model)

    def without_sensing(self, lay: Layout, floor: float, slack: float = 0.1) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray]:
        """Start and bounds of a "cholesky" NLP on which the sensing directions
        that ``lay`` holds at the floor of a "logchol" answer are switched off:
        a column of L whose norm is at most floor (1 + slack) (its diagonal at
        the floor up to the interior-point offset, ~1e-3 relative, nothing
        below it) is fixed at 0.
        The rest of L is free and away from the L = 0 saddle, so IPOPT converges
        near this point; the cost's gradient in a switched-off direction is
        positive at such an answer (its bound was active), which keeps the
        point stationary for the full problem. Returns (z0, lbz, ubz)."""
        if self.formulation != "cholesky":
            raise ValidationError("formulation", "without_sensing() needs the 'cholesky' NLP")
        return self.switch_off(self.pack(lay), self.lbz, self.ubz, floor, slack)

    @property
    def has_kalman_box(self) -> bool:
        """Whether the NLP lifts Q_k into factors M_k (info's "m_offset"
        places them), so that :meth:`kalman_box` bounds something: a
        stage-ordered form or an NLP with Q from the recursion has none."""
        return "m_offset" in self.info

    def kalman_box(self, lbz: np.ndarray, ubz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the bounds with every free entry of the lifted factors M_k
        within +-sqrt((W^-1)_ii) (row i): Q_k = (Y_{k-1}^-1 + W)^-1 < W^-1 on
        the Kalman equality (Lemma 2), so no feasible point is cut off; the box
        stops Newton steps that grow Q_k a thousandfold (docs/numerics.md,
        "The Kalman box"). Unchanged for an NLP without lifted Q."""
        lbz, ubz = np.array(lbz, float), np.array(ubz, float)
        if not self.has_kalman_box:
            return lbz, ubz
        K, tri, off = self.info["K"], self.info["tri"], self.info["m_offset"]
        cap = np.tile(np.sqrt(np.diag(np.linalg.inv(self.model.data.W)))[[i for i, _ in tri]], K - 1)
        idx = off + np.flatnonzero(lbz[off:off + cap.size] < ubz[off:off + cap.size])   # frozen entries stay
        lbz[idx] = np.maximum(lbz[idx], -cap[idx - off])
        ubz[idx] = np.minimum(ubz[idx], cap[idx - off])
        return lbz, ubz

    def switch_off(self, z: np.ndarray, lbz: np.ndarray, ubz: np.ndarray, floor: float,
                   slack: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the "cholesky" values ``z`` and bounds with the sensing
        that ``z`` holds at the floor switched off (columns of L fixed at 0:
        :func:`.nlp_matrices.switched_off` at level floor (1 + slack)), and
        a budget's levels held at their values, but those of the pairs the
        switch-off breaks: :meth:`without_sensing` of packed values, e.g. an
        earlier polish's answer, whose switched-off columns are 0 and stay off."""
        tri, d, K, off = self.info["tri"], self.info["d"], self.info["K"], self.info["sensing_offset"]
        z0, lbz, ubz = np.array(z, float), np.array(lbz, float), np.array(ubz, float)
        budget = bool(self.info.get("n_budget"))
        before = self.margin_values(z0)[0] if budget else None
        t = len(tri)
        L, off_cols = switched_off(lower_stack(z0[off:off + K * t].reshape(K, t), tri, d), floor * (1 + slack))
        z0[off:off + K * t] = L[:, [i for i, _ in tri], [j for _, j in tri]].ravel()
        col_of = np.array([j for _, j in tri])
        idx = off + np.flatnonzero(off_cols[:, col_of].ravel())           # entries of switched-off columns
        lbz[idx] = ubz[idx] = 0.0
        if budget:
            # the levels stay where the first stage allocated them, except those of
            # the pairs whose rows (two per pair, ordered as the levels) the switch-off
            # pushed below zero: only they re-balance. All fixed, the polish ended in
            # restoration at alpha = 1; all free, it crept at alpha = 0.1 (docs/numerics.md,
            # "Risk allocation in the NLP polish")
            n = K * self.info["J"]
            after = self.margin_values(z0)[0]
            broken = ((after < 0) & (after < before)).reshape(K, self.info["J"], 2).any(axis=2)
            if self.model.data.continuous:
                # a continuous budget's rows of transition k + 1 read Sigma_{k+1} through Q_k,
                # which re-closing step k's Kalman rows without its switched-off sensing moves:
                # those pairs re-balance too (held, 10 of 25 polishes at alpha = 1 ran to the cap)
                broken[1:] |= off_cols.any(axis=1)[:-1, None]
            held = z0.size - n + np.flatnonzero(~broken.ravel())
            lbz[held] = ubz[held] = z0[held]
        return z0, lbz, ubz


def _dims(model: BeliefModel, formulation: str) -> tuple:
    """Shapes both parts of :func:`build_nlp` read: the lower triangle's
    index pairs and length, the real faces per hazard and their offsets in a
    step's certificates, their count, whether Q is lifted, whether the
    formulation is one of the "cholesky" / "logchol" pair, whether a budget
    is set. ("cholesky" and "logchol" are one expression graph: L_ii =
    s exp(s w) + (1 - s) w is exp(w) at s = 1 and w at s = 0, bit for bit
    and so are its derivatives, so the two stages share one NLP and its
    derivatives: NLPProblem.variant.)"""
    D = model.data
    tri = _tri_index(D.d)
    nf = D.face_mask.sum(axis=1).astype(int)
    offs = np.concatenate([[0], np.cumsum(nf)])
    return (tri, len(tri), nf, offs, int(offs[-1]), formulation in ("cholesky", "logchol", "minors"),
            formulation in ("cholesky", "logchol"), D.budget is not None)


def _symbolic_graph(model: BeliefModel, formulation: str, margin: float, regularisation: float) -> dict:
    """The symbolic part of :func:`build_nlp` (most of its time): the
    expressions of the objective, the rows and the cost parts as one CasADi
    function of (z, p), and the row counts. A dict that pickles (CasADi
    serialises the function), so the disk cache can keep it."""
    D = model.data
    K, d, J, F = D.K, D.d, D.J, D.F
    tri, t, nf, offs, n_lam, lift_q, pair, budget = _dims(model, formulation)
    switch = ca.SX.sym("logchol")

    X = ca.SX.sym("x", d, K)
    Sv = ca.SX.sym("s", t, K)
    Mv = ca.SX.sym("m", t, K - 1) if lift_q else ca.SX(t, 0)
    Lam = ca.SX.sym("lam", n_lam, K)
    Tau = ca.SX.sym("tau", J, K) if budget else ca.SX(J, 0)       # column k-1 = the levels of transition k
    W = ca.DM(D.W)
    # the start belief is a parameter (start_values), not a constant: a re-plan
    # from a new belief reuses the graph, its derivatives and the solver
    x0, P0, Q1, logdet_q1, relief = _start_symbols(d)
    xs = [x0] + [X[:, k] for k in range(K)]

    Q: list = [None, Q1]
    logdet_q: list = [None, logdet_q1]
    Y: list = [None]
    g_kal, g_psd = [], []
    for k in range(1, K + 1):
        if k >= 2:
            if lift_q:
                Mk = _lower(Mv[:, k - 2], tri, d)
                Qk = Mk @ Mk.T
                logdet_q.append(2 * ca.sum1(ca.log(ca.diag(Mk))))
                gap = model.f_kalman(Qk, Y[k - 1])       # terms.kalman_residual (Lemma 2: = 0)
                g_kal.append(ca.vertcat(*[gap[i, j] for i, j in tri]))
            else:
                Qk = ca.inv(ca.inv(Y[k - 1]) + W)        # the Kalman recursion itself
                Qk = 0.5 * (Qk + Qk.T)
                logdet_q.append(terms.logdet(Qk))
            Q.append(Qk)
        if formulation == "minors":
            Sk = _symmetric(Sv[:, k - 1], tri, d)
            for r in range(1, d + 1):
                for rows in map(list, combinations(range(d), r)):
                    g_psd.append(ca.det(Sk[rows, rows]))
        else:
            Lk = _lower(Sv[:, k - 1], tri, d)
            if pair:
                w = ca.diag(Lk)
                Lk = ca.tril(Lk, False) + ca.diag(switch * ca.exp(switch * w) + (1 - switch) * w)
            Sk = Lk @ Lk.T
        Y.append(Q[k] + Sk)

    control = D.sigma ** 2 * sum(terms.control(xs[k - 1], xs[k]) for k in range(1, K + 1))
    information = 0.5 * sum(terms.logdet(Y[k]) - logdet_q[k] for k in range(1, K + 1))

    # collision constraints (Theorem 1, common lambda), ordered (k, j, start/end)
    g_col = []
    # continuous-time surrogate: both ends under Sigma_k = Q_{k-1}^-1 + W (Sigma_1 = P0 + W),
    # information T_k (risk.continuous_surrogate)
    T = [None, Q1] + [_sym_inv(ca.inv(Q[k - 1]) + W) for k in range(2, K + 1)] if D.continuous else None
    AB = [(ca.DM(D.A[j]), ca.DM(D.b[j])) for j in range(J)]       # once per hazard, not per (k, j)
    pads = [ca.SX.zeros(F - nf[j]) for j in range(J)]
    for k in range(1, K + 1):
        lam_k = ca.vertsplit(Lam[:, k - 1], [int(o) for o in offs])
        for j in range(J):
            lam = ca.vertcat(lam_k[j], pads[j])
            A, b = AB[j]
            # the model's margins are at level chi2; a variable level moves them by chi2 - tau (1 + margin)
            shift = D.chi2 - (1 + margin) * Tau[j, k - 1] if budget else 0
            if T is not None:
                g_col.append(model.f_margin_inv(xs[k - 1], T[k], lam, A, b) + shift)
                g_col.append(model.f_margin_inv(xs[k], T[k], lam, A, b) + shift)
                continue
            if k == 1:
                # transition 1 at the start's own level chi2 - relief (start_confidence): both ends
                g_col.append(model.f_margin_cov(xs[0], P0, lam, A, b) + shift + relief)
                g_col.append(model.f_margin_inv(xs[1], Q[1], lam, A, b) + shift + relief)
                continue
            g_col.append(model.f_margin_inv(xs[k - 1], Y[k - 1], lam, A, b) + shift)
            g_col.append(model.f_margin_inv(xs[k], Q[k], lam, A, b) + shift)
    g_tgt = [model.f_target(xs[K], Y[K], ca.DM(D.At[n]), D.bt[n]) for n in range(D.At.shape[0])]

    Lam0 = ca.SX.sym("lam0", n_lam, K)
    alpha = ca.SX.sym("alpha")
    reg = 0.5 * regularisation * ca.sumsqr(Lam - Lam0)
    p = ca.vertcat(ca.vec(Lam0), x0, ca.vec(P0), ca.vec(Q1), logdet_q1, relief, alpha, switch)

    z = ca.veccat(X, Sv, Mv, Lam, Tau)
    g_col_v = ca.vertcat(*g_col)
    g_tgt_v = ca.vertcat(*g_tgt)
    # the budget in its own units: sum g(tau) / budget <= 1, g(tau) = Phi_bar(sqrt(tau)) exactly
    g_bud = [ca.sum1(0.5 * (1 - ca.erf(ca.sqrt(ca.vec(Tau) / 2)))) / D.budget] if budget else []
    g = ca.vertcat(g_col_v, g_tgt_v, *g_kal, *g_psd, *g_bud)
    f = control + alpha * information + reg
    # the model's terms are mapped per hazard, each recomputing its step's
    # inverse: eliminating the common subexpressions (exact: the same
    # operations on the same inputs) halves the derivatives' size, their
    # construction and evaluation time (docs/numerics.md, "Construction cost")
    fg = ca.cse(ca.vertcat(f, g))
    f, g = fg[0], fg[1:]
    n_col, n_tgt, n_kal, n_psd = len(g_col), len(g_tgt), t * len(g_kal), len(g_psd)
    return {"function": ca.Function("belief_nlp_graph", [z, p], [f, g, control, information, reg, g_col_v, g_tgt_v]),
            "counts": (n_col, n_tgt, n_kal, n_psd, len(g_bud))}


def _start_symbols(d: int) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX]:
    """x0, P0, Q1 = (P0 + W)^-1, log det Q1 and the start's relief (chi2 -
    chi2_start) as symbols: the parameters :func:`start_values` gives values."""
    return (ca.SX.sym("x0", d), ca.SX.sym("P0", d, d), ca.SX.sym("Q1", d, d), ca.SX.sym("logdet_q1"),
            ca.SX.sym("relief"))


def start_values(D: ProblemData) -> np.ndarray:
    """The start belief of ``D`` as the NLP's parameters (x0, P0, Q1, log det
    Q1, relief; matrices column-major as ``ca.vec``). Q1 and its
    log-determinant are computed here in numpy, as the constants they
    replaced were."""
    return np.concatenate([D.x0, D.P0.ravel(order="F"), D.Q1.ravel(order="F"),
                           [float(np.linalg.slogdet(D.Q1)[1]), D.relief]])


def build_nlp(model: BeliefModel, formulation: str = "cholesky", margin: float = 1e-6,
              regularisation: float = 1e-4, floor: float = 1e-2, graph: dict | None = None) -> NLPProblem:
    """Build the NLP of the module docstring from ``model``'s CasADi functions.

    formulation : "cholesky" (S = L L^T, Q_k = M_k M_k^T lifted with the Kalman
        equality; default), "logchol" (as "cholesky" with L_ii = exp(w_i),
        w_i >= log(floor): keeps the iterates off the L = 0 saddle; its answer
        senses at least floor^2 per axis, so a "cholesky" polish follows it),
        "minors" (S symmetric, kept PSD by its principal minors; Q as
        "cholesky") or "eliminated" (S = L L^T, Q_k given by the
        Kalman recursion, no Q variables).
    margin : relative clearance margin kept in every collision constraint
        (m = margin * chi2) and absolute one (scaled length) in containment.
    regularisation : eps of the certificates' proximal term (0 to drop it);
        its centre lam_0 is the NLP's parameter (``NLPProblem.anchor``), as is alpha.
    floor : smallest diagonal entry of L (scaled units) for "logchol".
    graph : the symbolic part of an earlier build of the same model,
        formulation family, margin and regularisation (``NLPProblem.graph``,
        e.g. from the disk cache): its expressions are re-created from it
        (the same operations: ~0.04 s instead of ~0.35 s at K = 20) and only
        the numeric parts are built.
    """
    if formulation not in FORMULATIONS:
        raise ValidationError("formulation", f"must be one of {FORMULATIONS}, got {formulation!r}")
    D = model.data
    K, d, J, F = D.K, D.d, D.J, D.F
    tri, t, nf, offs, n_lam, lift_q, pair, budget = _dims(model, formulation)
    diag_pos = [tri.index((i, i)) for i in range(d)]
    if graph is None:
        graph = _symbolic_graph(model, formulation, margin, regularisation)
    z, p = graph["function"].sx_in()
    f, g, control, information, reg, g_col_v, g_tgt_v = graph["function"].call([z, p])
    switch = p[p.numel() - 1]
    n_start = start_values(D).size
    start = p[n_lam * K:n_lam * K + n_start]          # the start belief's entries of p (start_values)
    n_col, n_tgt, n_kal, n_psd, n_bud = graph["counts"]
    lbg = np.concatenate([np.full(n_col, 0.0 if budget else margin * D.chi2), np.full(n_tgt, margin),
                          np.zeros(n_kal), np.zeros(n_psd), np.full(n_bud, -np.inf)])
    ubg = np.concatenate([np.full(n_col + n_tgt, np.inf), np.zeros(n_kal), np.full(n_psd, np.inf),
                          np.ones(n_bud)])

    nX, nS, nM = d * K, t * K, t * (K - 1) if lift_q else 0
    lbz = np.full(z.shape[0], -np.inf)
    ubz = np.full(z.shape[0], np.inf)
    if lift_q:
        m_lb = np.full((t, K - 1), -np.inf)
        m_lb[diag_pos, :] = 1e-8                       # M_k,ii > 0: log det Q_k defined
        lbz[nX + nS:nX + nS + nM] = m_lb.ravel(order="F")
    nL = n_lam * K
    lbz[nX + nS + nM:nX + nS + nM + nL] = 0.0          # lam >= 0
    if budget:
        tau_lo, tau_hi = D.level_bounds
        lbz[nX + nS + nM + nL:] = tau_lo
        ubz[nX + nS + nM + nL:] = tau_hi
    parts = ca.Function("parts", [z, p], [control, information, reg], ["z", "p"],
                        ["control", "information", "regulariser"])

    def _packing(formulation: str, floor: float) -> tuple[Callable, Callable]:
        """pack (Layout -> z values) and unpack (z values -> Layout) of ``formulation``."""
        ti, tj = [i for i, _ in tri], [j for _, j in tri]

        def pack(lay: Layout) -> np.ndarray:
            Xv = lay.x[1:].T
            if formulation == "minors":
                Sp = np.stack([[0.5 * (lay.S[k][i, j] + lay.S[k][j, i]) for i, j in tri]
                               for k in range(1, K + 1)], 1)
            else:
                # every step's factor in one stacked call: numpy runs the same
                # LAPACK / BLAS kernel on each matrix, so the same values as one at a time
                Ls = _psd_factor(np.asarray(lay.S[1:K + 1], float))
                if formulation == "logchol":
                    for Lk in Ls:   # lifted to the floor (more sensing: the start stays safe)
                        Lk[np.diag_indices(d)] = np.log(np.maximum(np.diag(Lk), floor))
                Sp = Ls[:, ti, tj].T
            parts_ = [Xv.ravel(order="F"), Sp.ravel(order="F")]
            if lift_q:
                Q = np.asarray(lay.Q[2:K + 1], float)
                Mp = np.linalg.cholesky(0.5 * (Q + np.swapaxes(Q, -1, -2)))[:, ti, tj].T if K > 1 \
                    else np.zeros((t, 0))
                parts_.append(Mp.ravel(order="F"))
            parts_.append(lam_values(lay))
            if budget:
                parts_.append(np.asarray(lay.tau, float).T.ravel(order="F"))
            return np.concatenate(parts_)

        def unpack(zv: np.ndarray, model: BeliefModel) -> Layout:
            zv = np.asarray(zv, float).ravel()
            x = np.vstack([model.data.x0[None], zv[:nX].reshape(K, d)])
            Sp = zv[nX:nX + nS].reshape(K, t)
            S = np.zeros((K + 1, d, d))
            for k in range(1, K + 1):
                M = np.zeros((d, d))
                for p, (i, j) in enumerate(tri):
                    M[i, j] = Sp[k - 1, p]
                if formulation == "logchol":
                    M[np.diag_indices(d)] = np.exp(np.diag(M))
                if formulation == "minors":
                    Ssym = M + M.T - np.diag(np.diag(M))
                    w, V = np.linalg.eigh(Ssym)
                    S[k] = (V * np.maximum(w, 0.0)) @ V.T      # bound_relax_factor allows ~1e-8 negative minors
                else:
                    S[k] = M @ M.T
            Qm = np.zeros((K + 1, d, d))
            Qm[1] = model.data.Q1
            if lift_q and K > 1:
                Mp = zv[nX + nS:nX + nS + nM].reshape(K - 1, t)
                for k in range(2, K + 1):
                    M = np.zeros((d, d))
                    for p, (i, j) in enumerate(tri):
                        M[i, j] = Mp[k - 2, p]
                    Qm[k] = M @ M.T
            lam_c = zv[nX + nS + nM:nX + nS + nM + n_lam * K].reshape(K, n_lam)
            lam = np.zeros((K, J, F))
            for j in range(J):
                lam[:, j, :nf[j]] = lam_c[:, offs[j]:offs[j + 1]]
            tau = zv[nX + nS + nM + n_lam * K:].reshape(K, J).copy() if budget else None
            lay = Layout(x, Qm, S, lam, tau)
            if not lift_q:
                lay = model.tighten(lay)
            return lay

        return pack, unpack

    def view(formulation: str, floor: float) -> NLPProblem:
        """The NLP as ``formulation`` (one of the pair when ``pair``) sees it."""
        lb = lbz.copy()
        if formulation == "logchol":
            s_lb = np.full((t, K), -np.inf)
            s_lb[diag_pos, :] = np.log(floor)
            lb[nX:nX + nS] = s_lb.ravel(order="F")
        pack, unpack = _packing(formulation, floor)
        on = ca.SX(1.0 if formulation == "logchol" else 0.0)
        margins = ca.Function("margins", [z, start], ca.substitute([g_col_v, g_tgt_v], [switch], [on]),
                              ["z", "start"], ["collision", "target"])

        def anchor(lay: Layout, alpha: float | None, model: BeliefModel) -> np.ndarray:
            return np.concatenate([lam_values(lay), start_values(model.data),
                                   [model.data.alpha if alpha is None else float(alpha),
                                    1.0 if formulation == "logchol" else 0.0]])

        return NLPProblem(formulation, z, p, f, g, lb, ubz, lbg, ubg, parts, margins, pack, unpack, anchor, n_col,
                          model,
                          info={"n_variables": int(z.shape[0]), "n_constraints": int(g.shape[0]),
                                "n_kalman": n_kal, "n_psd": n_psd, "n_target": n_tgt, "n_budget": n_bud,
                                "sensing_offset": nX, "tri": tri, "d": d, "K": K, "J": J, "floor": floor,
                                **({"m_offset": nX + nS} if lift_q else {})},
                          _view=view if pair else None, graph=graph)

    def lam_values(lay: Layout) -> np.ndarray:
        return np.concatenate([lay.lam[:, j, :nf[j]] for j in range(J)], axis=1).T.ravel(order="F")

    return view(formulation, floor)
