"""IPOPT baseline: the whole smoothing problem as one NLP, solved by IPOPT
through CasADi's ``nlpsol``, from the same warm start as CCP.

Use :func:`belief_nlp.smooth` with ``method="ipopt"`` rather than calling
:func:`ipopt` directly.

The NLP (prob_2 of the paper with the errata; scaled units of model.py)
------------------------------------------------------------------------
Every piece of maths comes from :class:`~belief_nlp.nlp.model.BeliefModel`'s
CasADi functions (``f_end_margin``, ``f_start_margin_P``, ``f_containment``,
``f_kalman``, ``f_logdet_grad``); this module only chooses the variables.

Variables, k = 1..K: means x_k; sensing S_k = L_k L_k^T (L_k lower
triangular, free signs -- every L gives S >= 0, so no PSD constraint is
needed and S = 0 is the smooth point L = 0); prior information
Q_k = M_k M_k^T for k >= 2 (diagonal of M_k bounded below by 1e-8, so
log det Q_k = 2 sum log M_k,ii); Q_1 = (P0 + W)^-1 is fixed (errata 8); one
certificate lam_{k,j} >= 0 per transition and hazard (Theorem 1 with errata
5), only for the hazard's real faces.

    min  sigma^2 sum_k ||x_k - x_{k-1}||^2 + alpha/2 sum_k (log det Y_k - log det Q_k)
         + eps/2 ||lam - lam_0||^2                                   (see "regulariser")
    s.t. Q_k^-1 - Y_{k-1}^-1 - W = 0                       k >= 2   (Kalman, Lemma 2)
         -v^T Y_{k-1}^-1 v + 2 lam^T (A x_{k-1} - b) - chi2 >= m     k >= 2   (tran_col_1)
         -v^T P0 v        + 2 lam^T (A x_0 - b)     - chi2 >= m     k = 1    (errata 8)
         -v^T Q_k^-1 v    + 2 lam^T (A x_k - b)     - chi2 >= m     all k    (tran_col_2)
         b_n - a_n^T x_K - chi sqrt(a_n^T Y_K^-1 a_n) >= m'                 (final_cond)
    with Y_k = Q_k + S_k, v = A_j^T lam_{k,j}, m = 1e-6 chi2, m' = 1e-6 (scaled length).

Settings and why (measurements)
-------------------------------
Two test sets on paper-multi, both alphas, the criterion being "IPOPT
reports success, the path passes verify, cost within 1 % of CCP's converged
value or lower": set A, 24 runs (the hand path of tests/conftest.py at K = 20
and 40, ten per-step IG-RRT* plans at one step per edge, K = 7..12); set B,
38 runs (IG-RRT* seeds 10-19 planned at alpha = 0.1 and 1.0, K = 3..20).
Each line changes one thing against the defaults (this module's code; the
last block was measured on its prototype, set A only).

=====================================================  ===========  ===========
variant                                                set A        set B
=====================================================  ===========  ===========
defaults                                               24/24        38/38
                                                       median 192 / 260 iterations
no restart (``restarts=0``)                            24/24        37/38 (crept to
                                                                    the 3000 limit)
no proximal term (``regularisation=0``)                22/24        37/38
``regularisation=1e-3`` (cost bias 0.1-0.4 %)          24/24        38/38
S by principal minors (``formulation="minors"``)       24/24        36/38
Q eliminated by the recursion (``"eliminated"``)       24/24, 5x    37/38, 2.5x
                                                       slower       slower
monotone mu (IPOPT's default)                          23/24        35/38
bound_push = bound_frac = 1e-2 (IPOPT's default)       24/24        37/38
IPOPT defaults (monotone mu, bound push 1e-2,          3/24, median 1210 iterations
tol 1e-8, constr_viol_tol 1e-4), no proximal term,
no restart
the same with Q eliminated (numerics.md's setting)     0 of the first 7 (20-90 s each;
                                                       stopped)
-----------------------------------------------------  ------------------------
relaxed Kalman inequality (by minors) instead of =     0/24
lengths in metres instead of sigma units               21/24
start lam at the margin-maximising lambda*             11/24
limited-memory Hessian (L-BFGS)                        1/24
exp-parameterised diagonal of M (instead of bounds)    20/24
L with a positive diagonal (bounds)                    22/24
=====================================================  ========================

Why these work:

* **Lifting Q** (Q_k = M_k M_k^T as variables tied by the Kalman equality --
  "multiple shooting") keeps every constraint local in k; eliminating Q nests
  K inverses in every expression (deep, dense Hessian, 20-30 ms per
  iteration against 5-7 ms).
* **Equality, not the relaxed Kalman inequality.** The relaxation of prob_2
  (Q_k^-1 >= Y_{k-1}^-1 + W) is tight at the optimum (Lemma 2); as an
  inequality the PSD matrix is 0 there and every principal minor is active
  with a zero gradient: degenerate, and IPOPT never converged.
* **A tiny proximal term on the certificates**, eps/2 ||lam - lam_0||^2 with
  eps = 1e-4 and lam_0 the start's certificates (an NLP parameter). For a
  hazard far from the path, lam may move in a large set without changing
  anything: the Lagrangian is flat there. Once mu was small, IPOPT took huge
  steps along these directions (seen as many far-away lam growing at once),
  the concave quadratic constraints overshot and it fell into restoration --
  often right at the optimum. The term gives those directions curvature eps
  and biases the cost by O(eps): measured 0.01-0.04 % at 1e-4.
* **Adaptive mu** (LOQO oracle), **bound_push = bound_frac = 1e-4** (the
  warm start is already interior; the default 1e-2 push undoes part of it),
  **tol = 1e-4** (IPOPT's scaled KKT error; final costs within 0.1 % of the
  tol = 1e-8 answers in half the iterations) with **constr_viol_tol = 1e-8**
  (below the 1e-6 chi2 margin kept in every collision row, so answers pass
  the exact check).
* **Certificates**: the warm start's smallest valid ones (warmstart.py) start
  IPOPT near the active side of every pair; the margin-maximising lambda*
  gives large constraint curvature and worse convergence.
* **Restart on a stall**: twice in 62 runs IPOPT crept for >1000 iterations
  next to the optimum (watchdog steps, tiny line-search steps, dual
  infeasibility stuck near 7e-5). An attempt that has been feasible without
  lowering the cost for ``stall`` = 300 iterations (or that hits its share of
  the iteration budget, or fails) is stopped and IPOPT restarted from the
  best exactly safe point with a fresh barrier and filter; both then
  converged within ~100 more iterations.

History. ``SmoothResult.history[0]`` is the warm start; then one record per
IPOPT iteration (restarts continue the count): its cost parts, ``min_margin``
= the smallest NLP margin (certificate value of the collision rows, a lower
bound on the squared Mahalanobis clearance minus chi2, and the target rows),
``accepted`` = the iterate satisfies the NLP's constraints to 1e-6,
``kalman_gap`` = the largest Kalman-equality residual (relative, scaled
units), ``wall_time`` = time since the previous iteration.

Every answer is checked like CCP's iterates: exact continuous-time clearance
(geometry.transition_minimiser) on the Kalman-consistent path
(model.tighten -> model.to_path), target containment, then
:func:`belief_nlp.verify`. If IPOPT's last point fails, the best (lowest
cost) IPOPT iterate that satisfied the NLP's constraints and passes the same
checks is returned, at worst the warm start, with ``success=False``.
"""

from __future__ import annotations

import heapq
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable

import casadi as ca
import numpy as np

from ..errors import SolverError, ValidationError
from ..geometry import PolytopeSet, transition_minimiser
from ..scenario import Scenario
from .model import BeliefModel, Layout
from .result import STATUSES, IterationRecord, SmoothResult
from .warmstart import WarmStart

__all__ = ["ipopt", "build_nlp", "NLPProblem", "FORMULATIONS", "DEFAULT_IPOPT_OPTIONS", "map_status", "clear_cache"]

log = logging.getLogger("belief_nlp.smoother")

FORMULATIONS = ("cholesky", "minors", "eliminated")

#: IPOPT settings used unless ``solver_options`` overrides them (see module doc).
DEFAULT_IPOPT_OPTIONS: dict[str, Any] = {
    "mu_strategy": "adaptive",
    "mu_oracle": "loqo",
    "bound_push": 1e-4,
    "bound_frac": 1e-4,
    "constr_viol_tol": 1e-8,
    "print_level": 0,
    "sb": "yes",
}

DEFAULT_MAX_ITER = 3000

_CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
_MAX_ITER = {"Maximum_Iterations_Exceeded"}
_TIME = {"Maximum_CpuTime_Exceeded", "Maximum_WallTime_Exceeded"}


def map_status(ipopt_status: str) -> str:
    """IPOPT's return status -> one of :data:`~belief_nlp.nlp.result.STATUSES`
    (before the exact safety check, which may downgrade it)."""
    if ipopt_status in _CONVERGED:
        return "converged"
    if ipopt_status in _MAX_ITER:
        return "max_iter"
    if ipopt_status in _TIME:
        return "time_limit"
    return "ipopt_failed"


# ---------------------------------------------------------------- the NLP
@dataclass
class NLPProblem:
    """The smoothing problem as one CasADi NLP (scaled units of model.py).

    Attributes
    ----------
    z, p, f, g : CasADi SX decision vector, parameter (the certificates lam_0
        of the proximal term), objective and constraints.
    lbz, ubz, lbg, ubg : bounds (numpy).
    parts : Function (z, p) -> (control [m^2], information [nats], regulariser).
    margins : Function z -> (collision margins (2 K J,), target margins (N,));
        collision margins are the certificate values
        -v^T P v + 2 lam^T (A x - b) - chi2 (a lower bound on the squared
        Mahalanobis clearance minus chi2), ordered (k, j, start/end).
    pack : Layout -> z values; unpack : z values -> Layout (S from its
        factor; Q as the variables say -- use model.tighten for the Kalman one).
    anchor : Layout -> p values (its certificates).
    n_collision : number of collision rows at the start of g.
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
    unpack: Callable[[np.ndarray], Layout]
    anchor: Callable[[Layout], np.ndarray]
    n_collision: int
    info: dict = field(default_factory=dict)


def _tri_index(d: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(d) for j in range(i + 1)]


def _lower(v: ca.SX, tri: list, d: int) -> ca.SX:
    M = ca.SX.zeros(d, d)
    for p, (i, j) in enumerate(tri):
        M[i, j] = v[p]
    return M


def _symmetric(v: ca.SX, tri: list, d: int) -> ca.SX:
    M = ca.SX.zeros(d, d)
    for p, (i, j) in enumerate(tri):
        M[i, j] = v[p]
        M[j, i] = v[p]
    return M


def _psd_factor(S: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the PSD part of S (a tiny jitter for S = 0)."""
    S = 0.5 * (S + S.T)
    w, V = np.linalg.eigh(S)
    Sp = (V * np.maximum(w, 0.0)) @ V.T
    jitter = 1e-12 * max(1.0, float(np.trace(Sp)))
    return np.linalg.cholesky(Sp + jitter * np.eye(S.shape[0]))


def build_nlp(model: BeliefModel, formulation: str = "cholesky", margin: float = 1e-6,
              regularisation: float = 1e-4) -> NLPProblem:
    """Build the NLP of the module docstring from ``model``'s CasADi functions.

    formulation : "cholesky" (S = L L^T, Q_k = M_k M_k^T lifted with the Kalman
        equality; default), "minors" (S symmetric, kept PSD by its principal
        minors; Q as "cholesky") or "eliminated" (S = L L^T, Q_k given by the
        Kalman recursion, no Q variables).
    margin : relative clearance margin kept in every collision constraint
        (m = margin * chi2) and absolute one (scaled length) in containment.
    regularisation : eps of the certificates' proximal term (0 to drop it);
        its centre lam_0 is the NLP's parameter (``NLPProblem.anchor``).
    """
    if formulation not in FORMULATIONS:
        raise ValidationError("formulation", f"must be one of {FORMULATIONS}, got {formulation!r}")
    D = model.data
    K, d, J, F = D.K, D.d, D.J, D.F
    tri = _tri_index(d)
    t = len(tri)
    diag_pos = [tri.index((i, i)) for i in range(d)]
    nf = D.face_mask.sum(axis=1).astype(int)
    offs = np.concatenate([[0], np.cumsum(nf)])
    n_lam = int(offs[-1])
    lift_q = formulation in ("cholesky", "minors")

    X = ca.SX.sym("x", d, K)
    Sv = ca.SX.sym("s", t, K)
    Mv = ca.SX.sym("m", t, K - 1) if lift_q else ca.SX(t, 0)
    Lam = ca.SX.sym("lam", n_lam, K)
    W = ca.DM(D.W)
    xs = [ca.DM(D.x0)] + [X[:, k] for k in range(K)]

    Q: list = [None, ca.DM(D.Q1)]
    logdet_q: list = [None, float(np.linalg.slogdet(D.Q1)[1])]
    Y: list = [None]
    g_kal, g_psd = [], []
    for k in range(1, K + 1):
        if k >= 2:
            if lift_q:
                Mk = _lower(Mv[:, k - 2], tri, d)
                Qk = Mk @ Mk.T
                logdet_q.append(2 * ca.sum1(ca.log(ca.diag(Mk))))
                gap = model.f_kalman(Qk, Y[k - 1])       # Q_k^-1 - Y_{k-1}^-1 - W (Lemma 2: = 0)
                g_kal.append(ca.vertcat(*[gap[i, j] for i, j in tri]))
            else:
                Qk = ca.inv(ca.inv(Y[k - 1]) + W)        # the Kalman recursion itself
                Qk = 0.5 * (Qk + Qk.T)
                logdet_q.append(model.f_logdet_grad(Qk)[0])
            Q.append(Qk)
        if formulation == "minors":
            Sk = _symmetric(Sv[:, k - 1], tri, d)
            for r in range(1, d + 1):
                for rows in _combinations(d, r):
                    g_psd.append(ca.det(Sk[rows, rows]))
        else:
            Lk = _lower(Sv[:, k - 1], tri, d)
            Sk = Lk @ Lk.T
        Y.append(Q[k] + Sk)

    control = D.sigma ** 2 * sum(ca.sumsqr(xs[k] - xs[k - 1]) for k in range(1, K + 1))
    information = 0.5 * sum(model.f_logdet_grad(Y[k])[0] - logdet_q[k] for k in range(1, K + 1))

    # collision constraints (Theorem 1, common lambda), ordered (k, j, start/end)
    g_col = []
    P0 = ca.DM(D.P0)
    for k in range(1, K + 1):
        for j in range(J):
            lam = ca.vertcat(Lam[offs[j]:offs[j + 1], k - 1], ca.SX.zeros(F - nf[j]))
            A, b = ca.DM(D.A[j]), ca.DM(D.b[j])
            if k == 1:
                g_col.append(model.f_start_margin_P(xs[0], P0, lam, A, b))
            else:
                g_col.append(model.f_end_margin(xs[k - 1], Y[k - 1], lam, A, b))
            g_col.append(model.f_end_margin(xs[k], Q[k], lam, A, b))
    g_tgt = [model.f_containment(xs[K], Y[K], ca.DM(D.At[n]), D.bt[n]) for n in range(D.At.shape[0])]

    Lam0 = ca.SX.sym("lam0", n_lam, K)
    reg = 0.5 * regularisation * ca.sumsqr(Lam - Lam0)
    p = ca.vec(Lam0)

    z = ca.veccat(X, Sv, Mv, Lam)
    g_col_v = ca.vertcat(*g_col)
    g_tgt_v = ca.vertcat(*g_tgt)
    g = ca.vertcat(g_col_v, g_tgt_v, *g_kal, *g_psd)
    n_col, n_tgt, n_kal, n_psd = len(g_col), len(g_tgt), t * len(g_kal), len(g_psd)
    lbg = np.concatenate([np.full(n_col, margin * D.chi2), np.full(n_tgt, margin), np.zeros(n_kal), np.zeros(n_psd)])
    ubg = np.concatenate([np.full(n_col + n_tgt, np.inf), np.zeros(n_kal), np.full(n_psd, np.inf)])

    nX, nS, nM = d * K, t * K, t * (K - 1) if lift_q else 0
    lbz = np.full(z.shape[0], -np.inf)
    ubz = np.full(z.shape[0], np.inf)
    if lift_q:
        m_lb = np.full((t, K - 1), -np.inf)
        m_lb[diag_pos, :] = 1e-8                       # M_k,ii > 0: log det Q_k defined
        lbz[nX + nS:nX + nS + nM] = m_lb.ravel(order="F")
    lbz[nX + nS + nM:] = 0.0                           # lam >= 0

    parts = ca.Function("parts", [z, p], [control, information, reg], ["z", "p"],
                        ["control", "information", "regulariser"])
    margins = ca.Function("margins", [z], [g_col_v, g_tgt_v], ["z"], ["collision", "target"])

    def pack(lay: Layout) -> np.ndarray:
        Xv = lay.x[1:].T
        if formulation == "minors":
            Sp = np.stack([[0.5 * (lay.S[k][i, j] + lay.S[k][j, i]) for i, j in tri] for k in range(1, K + 1)], 1)
        else:
            Sp = np.stack([[_psd_factor(lay.S[k])[i, j] for i, j in tri] for k in range(1, K + 1)], 1)
        parts_ = [Xv.ravel(order="F"), Sp.ravel(order="F")]
        if lift_q:
            Mp = np.stack([[np.linalg.cholesky(0.5 * (lay.Q[k] + lay.Q[k].T))[i, j] for i, j in tri]
                           for k in range(2, K + 1)], 1) if K > 1 else np.zeros((t, 0))
            parts_.append(Mp.ravel(order="F"))
        parts_.append(anchor(lay))
        return np.concatenate(parts_)

    def anchor(lay: Layout) -> np.ndarray:
        return np.concatenate([lay.lam[:, j, :nf[j]] for j in range(J)], axis=1).T.ravel(order="F")

    def unpack(zv: np.ndarray) -> Layout:
        zv = np.asarray(zv, float).ravel()
        x = np.vstack([D.x0[None], zv[:nX].reshape(K, d)])
        Sp = zv[nX:nX + nS].reshape(K, t)
        S = np.zeros((K + 1, d, d))
        for k in range(1, K + 1):
            M = np.zeros((d, d))
            for p, (i, j) in enumerate(tri):
                M[i, j] = Sp[k - 1, p]
            if formulation == "minors":
                Ssym = M + M.T - np.diag(np.diag(M))
                w, V = np.linalg.eigh(Ssym)
                S[k] = (V * np.maximum(w, 0.0)) @ V.T      # bound_relax_factor allows ~1e-8 negative minors
            else:
                S[k] = M @ M.T
        Qm = np.zeros((K + 1, d, d))
        Qm[1] = D.Q1
        if lift_q and K > 1:
            Mp = zv[nX + nS:nX + nS + nM].reshape(K - 1, t)
            for k in range(2, K + 1):
                M = np.zeros((d, d))
                for p, (i, j) in enumerate(tri):
                    M[i, j] = Mp[k - 2, p]
                Qm[k] = M @ M.T
        lam_c = zv[nX + nS + nM:].reshape(K, n_lam)
        lam = np.zeros((K, J, F))
        for j in range(J):
            lam[:, j, :nf[j]] = lam_c[:, offs[j]:offs[j + 1]]
        lay = Layout(x, Qm, S, lam)
        if not lift_q:
            lay = model.tighten(lay)
        return lay

    return NLPProblem(formulation, z, p, control + D.alpha * information + reg, g, lbz, ubz, lbg, ubg, parts,
                      margins, pack, unpack, anchor, n_col,
                      info={"n_variables": int(z.shape[0]), "n_constraints": int(g.shape[0]),
                            "n_kalman": n_kal, "n_psd": n_psd, "n_target": n_tgt})


def _combinations(n: int, r: int) -> list[list[int]]:
    from itertools import combinations

    return [list(c) for c in combinations(range(n), r)]


# ------------------------------------------------------------- callback
class _Recorder(ca.Callback):
    """IPOPT iteration callback: history, best feasible iterates, progress.

    One recorder serves every attempt (restart) of a solve; ``begin`` resets
    the per-attempt counter and sets the parameter values."""

    def __init__(self, nlp: NLPProblem, alpha: float, keep: int, bar, stall: int = 0):
        ca.Callback.__init__(self)
        self.nlp = nlp
        self.alpha = alpha
        self.nx = int(nlp.z.shape[0])
        self.ng = int(nlp.g.shape[0])
        self.keep = keep
        self.bar = bar
        self.calls = 0
        self.offset = 0
        self.pv = None
        self.budget = None
        self.deadline = None
        self.stop_reason = ""
        self.stall = stall
        self.best_cost = np.inf
        self.best_it = 0
        self.t_last = time.perf_counter()
        self.rows: list[tuple] = []            # (iteration, min margin, violation, dt, kalman gap)
        self.zs: list[np.ndarray] = []         # every iterate (for the history's costs and keep_iterates)
        self.pvs: list[np.ndarray] = []        # the parameter of each attempt
        self.best: list[tuple] = []            # min-heap of (-objective, iteration, z): the lowest
        self.construct("belief_nlp_ipopt_recorder", {})

    def reset(self, keep: int, bar, stall: int) -> None:
        """Forget a previous solve (the recorder lives as long as its solver)."""
        self.keep, self.bar, self.stall = keep, bar, stall
        self.calls = self.offset = 0
        self.rows, self.zs, self.pvs, self.best = [], [], [], []

    def begin(self, pv: np.ndarray, budget: int, deadline: float | None) -> None:
        """Start an attempt: parameter values, iteration budget and wall-clock
        deadline (the callback stops IPOPT at either; IPOPT then returns
        User_Requested_Stop and ``stop_reason`` says why)."""
        self.offset += max(self.calls - 1, 0)
        self.calls = 0
        self.pv = pv
        self.pvs.append(pv)
        self.budget = budget
        self.deadline = deadline
        self.stop_reason = ""
        self.best_cost = np.inf
        self.best_it = 0
        self.t_last = time.perf_counter()

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        # only x, f and g are used; empty multipliers keep the per-iteration
        # conversion cheap (the callback was 20 % of the solve time otherwise)
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.dense(1)
        if name == "x":
            return ca.Sparsity.dense(self.nx)
        if name == "g":
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        it = self.calls
        self.calls += 1
        now = time.perf_counter()
        dt, self.t_last = now - self.t_last, now
        if it == 0:                # IPOPT's iteration 0 is the start point itself
            return [0]
        it += self.offset
        zv = arg[0].full().ravel()
        gv = arg[2].full().ravel()
        cost = float(arg[1])                    # objective incl. the tiny proximal term: ranks iterates
        nlp = self.nlp
        viol = float(max(np.max(nlp.lbg - gv, initial=0.0), np.max(gv - nlp.ubg, initial=0.0)))
        n_col, n_tgt = nlp.n_collision, nlp.info["n_target"]
        min_margin = float(min(np.min(gv[:n_col], initial=np.inf), np.min(gv[n_col:n_col + n_tgt], initial=np.inf)))
        kal = gv[n_col + n_tgt:n_col + n_tgt + nlp.info["n_kalman"]]
        # Kalman rows are entries of Q_k^-1 - Y_{k-1}^-1 - W in scaled units, where
        # ||Y^-1 + W|| >= ||W'|| = 1: the largest one is a relative gap
        kgap = float(np.max(np.abs(kal), initial=0.0))
        self.rows.append((it, min_margin, viol, dt, kgap))
        self.zs.append(zv)                      # cost parts evaluated in one batch after the solve
        # candidates for the fallback: iterates feasible for the NLP
        feasible = viol <= 1e-6 and np.isfinite(cost)     # candidates; the exact check decides
        if feasible and cost < self.best_cost * (1 - 1e-7):
            self.best_cost, self.best_it = cost, self.calls - 1
        if feasible:
            item = (-cost, it, zv)
            if len(self.best) < self.keep:
                heapq.heappush(self.best, item)
            elif self.keep and item > self.best[0]:
                heapq.heapreplace(self.best, item)
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(cost=f"{cost:.5g}", viol=f"{viol:.1e}")
        if self.budget is not None and self.calls - 1 >= self.budget:
            self.stop_reason = "max_iter"
            return [1]
        if self.deadline is not None and now > self.deadline:
            self.stop_reason = "time_limit"
            return [1]
        if self.stall and feasible and self.calls - 1 - self.best_it >= self.stall:
            # feasible, but no feasible iterate has lowered the cost for `stall`
            # iterations: IPOPT is creeping (seen as long runs of tiny steps and
            # watchdog trials next to an optimum); stop so a restart can finish
            self.stop_reason = "stalled"
            return [1]
        return [0]


# ------------------------------------------------------------- checking
def _exact_check(model: BeliefModel, z: Layout, hazards: PolytopeSet) -> tuple[Layout, bool]:
    """Kalman-consistent layout (Lemma 2) and whether it is exactly safe:
    continuous-time clearance min(dist2) >= chi2 for every transition and
    hazard (geometry.transition_minimiser) and the final ellipse in the target."""
    zt = model.tighten(z)
    path = model.to_path(zt)
    tm = transition_minimiser(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise, hazards)
    ok = bool(np.min(tm.dist2) >= model.data.chi2 and np.min(model.target_margins(zt)) >= 0)
    return zt, ok


def _exact_margin(model: BeliefModel, z: Layout, hazards: PolytopeSet) -> float:
    path = model.to_path(z)
    tm = transition_minimiser(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise, hazards)
    return float(np.min(tm.dist2) - model.data.chi2)


def _ipopt_options(solver_options: dict | None, max_iter: int, tol: float) -> dict:
    opts = dict(DEFAULT_IPOPT_OPTIONS)
    opts["max_iter"] = int(max_iter)
    opts["tol"] = float(tol)
    for key, value in (solver_options or {}).items():
        key = key[len("ipopt."):] if key.startswith("ipopt.") else key
        opts[key] = value
    return opts


def _safe_points(model: BeliefModel, nlp: NLPProblem, recorder: _Recorder, z_end: np.ndarray | None,
                 hazards: PolytopeSet, converged: bool) -> list[tuple[float, Layout, str, int | None]]:
    """Exactly safe points among IPOPT's last point and the recorded feasible
    iterates, as (cost, Kalman-consistent layout, description, iteration).
    When IPOPT converged and its last point is safe, that point alone."""
    pool = []
    if z_end is not None and np.all(np.isfinite(z_end)):
        pool.append((None, z_end))
    pool += [(it, zv) for _, it, zv in recorder.best]
    found = []
    for it, zv in pool:
        try:
            zt, ok = _exact_check(model, nlp.unpack(zv), hazards)
        except np.linalg.LinAlgError:
            continue
        if not ok:
            continue
        where = "IPOPT's final point" if it is None else f"IPOPT iterate {it} (the best feasible one)"
        found.append((model.cost(zt)[0], zt, where, it))
        if it is None and converged:
            return found
    return found


# ------------------------------------------------------------------ cache
# (id(scenario), key) -> (scenario, (nlp, solver, recorder)), least recently
# used first. Scenarios are not hashable (they compare by content), so entries
# are keyed by identity and hold their scenario (a bounded number of them).
_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()
_CACHE_SIZE = 6


def _cache_get(scenario: Scenario, key: tuple):
    hit = _CACHE.get((id(scenario), key))
    if hit is None or hit[0] is not scenario:
        return None
    _CACHE.move_to_end((id(scenario), key))
    return hit[1]


def _cache_put(scenario: Scenario, key: tuple, entry: tuple) -> None:
    _CACHE[(id(scenario), key)] = (scenario, entry)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)


def clear_cache() -> None:
    """Drop every cached NLP / IPOPT instance."""
    _CACHE.clear()


# ------------------------------------------------------------------ main
def ipopt(scenario: Scenario, start: WarmStart, *, alpha: float | None = None, max_iter: int | None = None,
          tol: float = 1e-4, solver_options: dict | None = None, time_limit: float | None = None,
          keep_iterates: bool = False, progress: bool = False, formulation: str = "cholesky",
          regularisation: float = 1e-4, margin: float = 1e-6, restarts: int = 1, stall: int = 300,
          candidates: int = 5, cache: bool = True) -> SmoothResult:
    """Solve the smoothing problem with IPOPT from a warm start (see module doc).

    Use :func:`belief_nlp.smooth` with ``method="ipopt"``. Method options:

    formulation : "cholesky" (default), "minors" or "eliminated" (module doc).
    regularisation : eps of the certificates' proximal term (default 1e-4).
    margin : relative clearance margin kept in the constraints (1e-6).
    restarts : when IPOPT stops without converging (iteration limit, failed
        restoration, stalled), restart it this many times from the best
        exactly safe point found so far (default 1). With a restart allowed,
        the first attempt gets 2/3 of ``max_iter``.
    stall : with restarts, stop an attempt at a feasible iterate once no
        feasible iterate has lowered the cost for this many iterations (300).
    candidates : feasible IPOPT iterates kept for the fallback (5).
    cache : reuse the NLP and IPOPT instance built by an earlier call with the
        same scenario object, K, alpha, formulation and options (default
        True). Building them takes ~0.4 s at K = 20 (CasADi's symbolic
        Hessian); ``SmoothResult.timings["setup"]`` shows what a call paid.

    ``max_iter`` is IPOPT's total iteration limit (None: 3000); ``tol`` IPOPT's
    tolerance on its scaled KKT error; ``solver_options`` are IPOPT options
    (with or without an "ipopt." prefix) and override :data:`DEFAULT_IPOPT_OPTIONS`;
    ``time_limit`` bounds the wall time (IPOPT's max_wall_time);
    ``keep_iterates`` keeps every IPOPT iterate's path (they may be infeasible).
    """
    t_start = time.perf_counter()
    if max_iter is None:
        max_iter = DEFAULT_MAX_ITER
    for name, value in (("regularisation", regularisation), ("margin", margin)):
        if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
            raise ValidationError(name, f"must be a number >= 0, got {value!r}")
    if not isinstance(restarts, int) or isinstance(restarts, bool) or restarts < 0:
        raise ValidationError("restarts", f"must be an integer >= 0, got {restarts!r}")
    K = start.K
    model = BeliefModel(scenario, K, alpha)
    D = model.data
    hazards = PolytopeSet.build(scenario.hazards)

    z0 = model.tighten(model.from_path(start.path, start.lam))
    margin0 = _exact_margin(model, z0, hazards)
    cost0, ctrl0, info0 = model.cost(z0)

    opts = _ipopt_options(solver_options, max_iter, tol)
    max_iter = int(opts["max_iter"])
    key = (K, D.alpha, formulation, float(margin), float(regularisation), repr(sorted(opts.items())))
    entry = _cache_get(scenario, key) if cache else None
    if entry is None:
        nlp = build_nlp(model, formulation, margin=margin, regularisation=regularisation)
        recorder = _Recorder(nlp, D.alpha, keep=max(int(candidates), 0), bar=None, stall=0)
        try:
            solver = ca.nlpsol("belief_nlp_ipopt", "ipopt", {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                               {"ipopt": opts, "print_time": False, "iteration_callback": recorder,
                                "error_on_fail": False, "show_eval_warnings": False})
        except RuntimeError as exc:  # bad option names or values
            raise SolverError(f"IPOPT could not be set up: {exc}") from None
        if cache:
            _cache_put(scenario, key, (nlp, solver, recorder))
    else:
        nlp, solver, recorder = entry
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_iter, desc="IPOPT", unit="it")
    recorder.reset(keep=max(int(candidates), 0), bar=bar, stall=stall if restarts else 0)
    setup_time = time.perf_counter() - t_start

    # attempts: the first gets half the budget when a restart may follow
    used, solve_time, attempts = 0, 0.0, 0
    z_start, ipopt_status, z_end = z0, "not run", None
    statuses: list[str] = []
    best = (cost0, z0, "the warm start")         # lowest-cost exactly safe point so far
    answer = None                                # IPOPT's converged, exactly safe final point
    while True:
        remaining = max_iter - used
        budget = remaining if attempts >= restarts else max(1, remaining - remaining // 3)
        deadline = None if time_limit is None else t_start + time_limit
        if deadline is not None and time.perf_counter() >= deadline:
            ipopt_status = "Maximum_WallTime_Exceeded"
            break
        pv = nlp.anchor(z_start)
        recorder.begin(pv, budget, deadline)
        t_solve = time.perf_counter()
        try:
            sol = solver(x0=nlp.pack(z_start), p=pv, lbx=nlp.lbz, ubx=nlp.ubz, lbg=nlp.lbg, ubg=nlp.ubg)
            z_end = np.asarray(sol["x"]).ravel()
        except RuntimeError as exc:   # CasADi raises on some IPOPT exceptions
            log.warning("IPOPT raised: %s", exc)
            z_end = None
        solve_time += time.perf_counter() - t_solve
        stats = solver.stats()
        ipopt_status = str(stats.get("return_status", "unknown"))
        if ipopt_status == "User_Requested_Stop" and recorder.stop_reason:
            ipopt_status = {"max_iter": "Maximum_Iterations_Exceeded", "time_limit": "Maximum_WallTime_Exceeded",
                            "stalled": "Stalled"}[recorder.stop_reason]
        statuses.append(ipopt_status)
        used += int(stats.get("iter_count", 0))
        attempts += 1
        status = map_status(ipopt_status)
        found = _safe_points(model, nlp, recorder, z_end, hazards, status == "converged")
        if status == "converged" and found and found[0][3] is None:
            answer = found[0]
            break
        for cand in found:
            if cand[0] < best[0]:
                best = cand[:3]
        if attempts > restarts or status == "time_limit" or used >= max_iter or best[1] is z_start:
            break
        # restart IPOPT afresh (new barrier and filter) from the best safe point so far
        log.info("IPOPT %s after %d iterations; restarting from %s", ipopt_status, used, best[2])
        z_start = best[1]
    if bar is not None:
        bar.close()
    status = map_status(ipopt_status)

    # history: iteration 0 = warm start (exact margin), then one record per IPOPT iteration
    history = [IterationRecord(0, cost0, ctrl0, info0, "warm_start", min_margin=margin0, kalman_gap=0.0)]
    if recorder.zs:
        Z = np.stack(recorder.zs, axis=1)
        ctrls, infos, _ = (np.asarray(v).ravel() for v in nlp.parts.map(Z.shape[1])(Z, recorder.pvs[0]))
        for (it, mmin, viol, dt, kgap), ctrl, info in zip(recorder.rows, ctrls, infos):
            history.append(IterationRecord(it, float(ctrl + D.alpha * info), float(ctrl), float(info), "", dt, 0.0,
                                           dt, 1, accepted=viol <= 1e-6, min_margin=mmin, kalman_gap=kgap))
    if len(history) > 1:
        history[-1].solver_status = ipopt_status

    from ..verify import verify

    meta = {"method": "ipopt", "solver": "IPOPT", "alpha": D.alpha, "formulation": formulation,
            "ipopt_status": ipopt_status}
    final_is_answer = answer is not None
    _, chosen, chosen_from = (answer[:3] if answer is not None else best)
    path = model.to_path(chosen, meta=meta)
    report = verify(scenario, path)
    if not report.safe and chosen is not z0:
        log.warning("IPOPT answer failed verification (%s); returning the warm start", report.summary())
        chosen, chosen_from = z0, "the warm start (the answer failed independent verification)"
        path = model.to_path(z0, meta=meta)
        report = verify(scenario, path)
        final_is_answer = False
    tries = f" in {attempts} attempts ({', '.join(statuses)})" if attempts > 1 else ""
    if status == "converged" and not final_is_answer:
        status = "infeasible_iterate"
        message = (f"IPOPT returned {ipopt_status} after {used} iterations{tries}, but its last point failed "
                   f"the exact safety check; {chosen_from} is returned ({STATUSES[status]})")
    elif status == "converged":
        message = f"IPOPT returned {ipopt_status} after {used} iterations{tries}"
    else:
        message = (f"IPOPT returned {ipopt_status} after {used} iterations{tries}; {chosen_from} is returned "
                   f"({STATUSES[status]})")
    c, ctrl, info = model.cost(chosen)
    total = time.perf_counter() - t_start
    log.info("IPOPT (%s): %s, cost %.8g after %d iterations, %.2f s", formulation, ipopt_status, c, used, total)
    iterates = None
    if keep_iterates:
        iterates = [model.to_path(z0)] + [model.to_path(model.tighten(nlp.unpack(zv))) for zv in recorder.zs]
    return SmoothResult(
        path=path, cost=c, control=ctrl, information=info, success=status == "converged", status=status,
        message=message, nit=used, history=history, method="ipopt", solver="IPOPT", alpha=D.alpha,
        timings={"setup": setup_time, "solver": solve_time, "total": total},
        verification=report.to_dict(), initial_cost=cost0, iterates=iterates)
