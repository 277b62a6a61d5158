"""The DOC program of one (scenario, K, alpha) as a symbolic CasADi model, and
its convexification at a point: the form every CCP step solves.

The program (eq. main_doc with C4-C8; scaled units of :mod:`.data`), k = 1..K,
hazards j, target faces n:

    min  sigma^2 sum_k ||x_k - x_{k-1}||^2 + alpha/2 sum_k (log det Y_k - log det Q_k)
    s.t. S_k >= 0,  lam_kj >= 0,  Y_k = Q_k + S_k,  Q_1 = (P0 + W)^-1            (C8)
         kalman_lmi(Q_k, Y_{k-1}) >= 0                                  k >= 2  (C7)
         h1_lmi(R_kj, v_kj, Q_k) >= 0,  h2(R_kj, lam_kj, x_k) <= 0       end of k (C5, C6)
         h1_lmi(R'_kj, v_kj, Y_{k-1}) >= 0,  h2(R'_kj, lam_kj, x_{k-1}) <= 0   start, k >= 2
         v^T P0 v <= 2 lam^T (A x_0 - b) - chi2                          start, k = 1 (C8)
         target_lmis(x_K, C_n, Y_K) >= 0                                         (C4)

Under a risk budget (``D.budget``, :mod:`belief_nlp.allocation`) each pair's
chi2 is its own level tau_kj and sum_kj g(tau_kj) <= budget joins the
program. The step parameterises a level by its log risk l = log g(tau): the
budget is then exact (exponential cones) and the level tau = h(l), convex in l
with bounded curvature, enters both ends' h2 through a quadratic majorant
tight at the point (:func:`_level_majorant`), so the DOC structure survives.
The target keeps its own level ``D.chi2_target``. Under a continuous-time
budget (``D.continuous``) both ends of transition k use the information
T_k <= (Q_{k-1}^-1 + W)^-1 (a variable with the Kalman LMI's form, k >= 3;
T_1 = Q_1 and T_2 constants) and transition 1's start is a generic pair
(:func:`belief_nlp.risk.continuous_surrogate`).

Its two nonconvex pieces are concave: alpha/2 log det Y_k in the objective and
the bilinear h(lam, x) = 2 lam^T (A x - b) inside h2. The convexification at
the current point p (CCP, section IV.A) keeps every convex term exactly and
replaces
  * alpha/2 log det Y by its tangent at Y~ (CasADi's gradient);
  * h by its tangent at (lam~, x~) plus the remainder 2 dv^T dx (dv = A^T dlam,
    dx = x - x~), majorised as
        -2 dv^T dx <= 1/2 ||sqrt(rho) dv - dx / sqrt(rho)||^2
    (the other half of the split, -1/2 ||sqrt(rho) dv + dx / sqrt(rho)||^2, is
    concave with zero tangent at p). Any rho > 0 gives a convex majorant
    tight at p, so rho is a parameter that adapts per pair (docs/numerics.md,
    "The split of h2").
The means enter as steps dx = x - x~ (the variables stay O(step) and the
solver sees no cancellation between large constants).

Every cone family is an expression of the decision vector z, affine in z,
whose coefficients may depend on the parameter vector p (the current point,
rho and alpha, so that one compiled step serves every alpha of a scenario
and K). :mod:`.cvxpy_form` turns the families into one CVXPY problem
compiled once; the coefficient values for a point come from one generated
CasADi function.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from . import terms
from ..allocation import tail
from .data import Layout, ProblemData, psd_part, surrogate_information
from .cones import ConeFamily, _pick
from .doc_budget import _budget_families, _level_majorant

__all__ = ["ConeFamily", "ConvexForm", "StepLayout", "convex_form", "tangent"]

@dataclass
class Blocks:
    """Index maps of the subproblem's variables in z (-1: not a variable)."""

    x: np.ndarray      # (K+1, d) steps dx_k (row 0: the fixed start)
    Q: np.ndarray      # (K+1, d, d) symmetric, k >= 2
    S: np.ndarray      # (K+1, d, d) symmetric, k >= 1
    lam: np.ndarray    # (K, J, F) real faces only
    R_end: np.ndarray  # (K, J)   h1/h2 auxiliaries at the end of each transition
    R_start: np.ndarray  # (K, J) same at the start (row 0 unused: k = 1 is exact, C8)
    C: np.ndarray      # (N,)     target auxiliaries
    R0: np.ndarray     # (J,)     the exact k = 1 start end (C8), in units of eps0^2 (see convex_form)
    Z: np.ndarray      # (K+1, d, d) lower triangular, k >= 2 (log det epigraph)
    u: np.ndarray      # (K+1, d) k >= 2
    n: int
    T: np.ndarray | None = None     # (K+1, d, d) symmetric, k >= 3: Sigma_k^-1 of the continuous surrogate
    ell: np.ndarray | None = None   # (K, J) step dl of the log risk l = log g(tau) per pair (budget mode)
    e: np.ndarray | None = None     # (K, J) exp(l) in units of an even share, budget / (K J)
    up: np.ndarray | None = None    # (K, J) max(l - l~, 0) epigraphs
    dn: np.ndarray | None = None    # (K, J) max(l~ - l, 0) epigraphs


def _blocks(D: ProblemData) -> Blocks:
    K, J, F, d = D.K, D.J, D.F, D.d
    counter = [0]

    def alloc(shape) -> np.ndarray:
        size = int(np.prod(shape))
        out = np.arange(counter[0], counter[0] + size).reshape(shape)
        counter[0] += size
        return out

    ti, tj = np.triu_indices(d)

    def sym_map(ks) -> np.ndarray:
        out = -np.ones((K + 1, d, d), dtype=int)
        for k in ks:
            idx = alloc(ti.size)
            out[k, ti, tj] = idx
            out[k, tj, ti] = idx
        return out

    x = -np.ones((K + 1, d), dtype=int)
    x[1:] = alloc((K, d))
    Q = sym_map(range(2, K + 1))
    S = sym_map(range(1, K + 1))
    lam = -np.ones((K, J, F), dtype=int)
    lam[:, D.face_mask] = alloc((K, int(D.face_mask.sum())))
    R_end = alloc((K, J))
    R_start = -np.ones((K, J), dtype=int)
    if D.continuous:                       # every start end is a generic pair (no exact k = 1 form)
        R_start[:] = alloc((K, J))
    else:
        R_start[1:] = alloc((K - 1, J))
    C = alloc(D.At.shape[0])
    R0 = alloc(0 if D.continuous else J)
    Z = -np.ones((K + 1, d, d), dtype=int)
    u = -np.ones((K + 1, d), dtype=int)
    li, lj = np.tril_indices(d)
    for k in range(2, K + 1):
        Z[k, li, lj] = alloc(li.size)
        u[k] = alloc(d)
    T = sym_map(range(3, K + 1)) if D.continuous else None
    ell, e, up, dn = (alloc((K, J)) if D.budget is not None else None for _ in range(4))
    return Blocks(x, Q, S, lam, R_end, R_start, C, R0, Z, u, counter[0], T, ell, e, up, dn)


def tangent(f: ca.Function, n_lin: int | None = None) -> ca.Function:
    """Function (at_1..at_m, to_1..to_m, data...) -> the first-order Taylor
    expansion of ``f`` in its first m = ``n_lin`` inputs at ``at``, evaluated
    at ``to`` (the remaining inputs are data): the tangent CCP puts in place
    of a concave part, derivatives by CasADi. Build once, call per term."""
    m = f.n_in() if n_lin is None else n_lin
    shape = [f.sparsity_in(i).shape for i in range(f.n_in())]
    at = [ca.SX.sym(f"a{i}", *shape[i]) for i in range(m)]
    to = [ca.SX.sym(f"t{i}", *shape[i]) for i in range(m)]
    data = [ca.SX.sym(f"d{i}", *shape[i]) for i in range(m, f.n_in())]
    val = f(*at, *data)
    lin = val
    for a, t in zip(at, to):
        lin = lin + ca.mtimes(ca.jacobian(val, a), ca.vec(t - a))
    return ca.Function(f"{f.name()}_tangent", at + to + data, [lin])


def _pair_function(d: int, F: int, n_quad: int = 0) -> ca.Function:
    """One end of one (transition, hazard) pair at level ``chi2`` + 1/2 ||q||^2
    (``chi2`` affine: a constant, or the affine part of the pair's level
    majorant; ``q``: its ``n_quad`` quadratic parts, budget mode): the h1 LMI
    entries and the convexified h2 as a rotated second-order cone (module doc)."""
    lam, lt, R, chi2 = ca.SX.sym("lam", F), ca.SX.sym("lam_t", F), ca.SX.sym("R"), ca.SX.sym("chi2")
    q = ca.SX.sym("q", n_quad)
    x, xt, Y = ca.SX.sym("x", d), ca.SX.sym("x_t", d), ca.SX.sym("Y", d, d)
    A, b, r = ca.SX.sym("A", F, d), ca.SX.sym("b", F), ca.SX.sym("sqrt_rho")
    bil = tangent(ca.Function("bilinear", [lam, x, A, b], [terms.bilinear(lam, x, A, b)]), 2)
    h2_lin = R + chi2 - bil(lt, xt, lam, x, A, b)          # h2 with h replaced by its tangent
    dv = ca.mtimes(A.T, lam - lt)
    h1 = terms.h1_lmi(R, ca.mtimes(A.T, lam), Y)
    return ca.Function("collision_pair", [lam, lt, R, x, xt, Y, A, b, r, chi2, q],
                       [ca.vec(h1), _rsoc(-h2_lin, ca.vertcat(r * dv - (x - xt) / r, q))])


def step_start_values(D: ProblemData, K: int | None = None, at: int = 0) -> np.ndarray:
    """The start belief of ``D`` as the CCP step's parameters: x0, Q1,
    L0 / eps0, eps0^2 (:func:`start_factor`), T2 (matrices column-major) and
    each transition's relief off chi2: the start's chi2 - chi2_start at
    transition ``at`` + 1 (the first; a frozen prefix's step of ``K``
    transitions puts it after the prefix, :mod:`.conic_prefix`), 0 elsewhere."""
    L0, eps0 = start_factor(D.P0)
    relief = np.zeros(D.K if K is None else K)
    relief[at] = D.relief
    return np.concatenate([D.x0, D.Q1.ravel(order="F"), (L0 / eps0).ravel(order="F"), [eps0**2],
                           D.T2.ravel(order="F"), relief])


def start_factor(P0: np.ndarray) -> tuple[np.ndarray, float]:
    """(L0, eps0): P0 = L0 L0^T (P0 may be singular) and eps0 = ||L0||_2 (1 when P0 = 0)."""
    w0, V0 = np.linalg.eigh(P0)
    L0 = V0 * np.sqrt(np.maximum(w0, 0.0))
    eps0 = float(np.sqrt(max(float(np.max(w0)), 0.0)))
    return L0, (eps0 if eps0 > 0 else 1.0)


def _rsoc(w: ca.SX, y: ca.SX) -> ca.SX:
    """1/2 ||y||^2 <= w as the entries of one second-order cone (t, y, s)."""
    s2 = np.sqrt(2.0)
    return ca.vertcat((w + 1) / s2, y, (w - 1) / s2)


@dataclass
class StepLayout:
    """Where the model's quantities sit in z and p: numbers only (picklable),
    so a compiled problem loaded from disk needs no symbolic model."""

    data: ProblemData
    blocks: Blocks

    # --------------------------------------------------------- numeric maps
    def params(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray) -> np.ndarray:
        """Parameter vector of ``point`` with split weights rho (K, J) at both ends."""
        parts = [point.x.ravel(), point.Q.ravel(), point.S.ravel(), point.lam.ravel(),
                 np.asarray(rho_start, float).ravel(), np.asarray(rho_end, float).ravel()]
        if self.blocks.ell is not None:
            parts.append(np.asarray(point.tau, float).ravel())
        parts.append(step_start_values(self.data))
        parts.append([self.data.alpha])     # last: one compiled step serves every alpha (for_data)
        return np.concatenate(parts)

    def for_data(self, data: ProblemData) -> "StepLayout":
        """This layout with ``data``, which may differ from the layout's only in
        what the step takes as parameters (:meth:`params`): alpha and the start
        belief. The compiled problem stays."""
        return self if data is self.data else StepLayout(data, self.blocks)

    def point_vector(self, point: Layout) -> np.ndarray:
        """z of ``point`` itself (dx = 0) with every auxiliary at its tightest
        value: R = v^T Y^-1 v, C_n = 1 / sqrt(a^T Y_K^-1 a), Z = L diag(L) and
        u = log diag Z for Q = L L^T. A strictly feasible point is strictly
        feasible for its own convexification (tests check this)."""
        D, B = self.data, self.blocks
        K = D.K
        out = np.zeros(B.n)
        for imap, M in ((B.Q, point.Q), (B.S, point.S), (B.lam, point.lam)):
            keep = imap >= 0
            out[imap[keep]] = M[keep]
        v = np.einsum("jfd,kjf->kjd", D.A, point.lam)
        Y = point.Y
        if D.continuous:                    # both ends under T_k = Sigma_k^-1
            T = surrogate_information(D, point.Q)
            R = np.einsum("kjd,kjd->kj", v, np.linalg.solve(T[:, None], v[..., None])[..., 0])
            out[B.R_end] = out[B.R_start] = R
            keep = B.T >= 0
            out[B.T[keep]] = np.concatenate([np.zeros((1, D.d, D.d)), T])[keep]
        else:
            out[B.R_end] = np.einsum("kjd,kjd->kj", v, np.linalg.solve(point.Q[1:, None], v[..., None])[..., 0])
            if K > 1:
                out[B.R_start[1:]] = np.einsum("kjd,kjd->kj", v[1:],
                                               np.linalg.solve(Y[1:-1, None], v[1:, ..., None])[..., 0])
            L0, eps0 = start_factor(D.P0)
            out[B.R0] = np.sum((v[0] @ L0) ** 2, axis=-1) / eps0**2
        aYa = np.einsum("nd,nd->n", D.At, np.linalg.solve(Y[K], D.At.T).T)
        out[B.C] = 1.0 / np.sqrt(aYa)
        li, lj = np.tril_indices(D.d)
        for k in range(2, K + 1):
            L = np.linalg.cholesky(point.Q[k])
            Zk = L * np.diag(L)[None, :]
            out[B.Z[k, li, lj]] = Zk[li, lj]
            out[B.u[k]] = np.log(np.diag(Zk))
        if B.ell is not None:
            from ..allocation import tail

            q = tail(point.tau)
            out[B.ell] = 0.0
            out[B.e] = q / (D.budget / D.n_pairs)           # up = dn = 0: the majorant is tight here
        return out

    def variable_owners(self) -> np.ndarray:
        """(n,) the (transition, hazard) pair each variable of z belongs to, as
        k * J + j (0-based transition k; the pair's certificate and auxiliaries,
        as :attr:`ConeFamily.owner` for its cones), -1 for the others."""
        B = self.blocks
        out = np.full(B.n, -1)
        K, J = B.R_end.shape
        pair = np.arange(K * J).reshape(K, J)
        for imap, own in ((B.lam, np.broadcast_to(pair[..., None], B.lam.shape)), (B.R_end, pair),
                          (B.R_start, pair), (B.R0, pair[0, :B.R0.size])):
            ok = imap >= 0
            out[imap[ok]] = own[ok]
        return out

    def extract(self, zv: np.ndarray, point: Layout) -> Layout:
        """The new point from a solution vector (means = x~ + dx). S is projected
        on the PSD cone (the solver keeps S >= 0 only to its tolerance; more
        sensing can only shrink ellipses), lam on lam >= 0."""
        D, B = self.data, self.blocks
        K, d = D.K, D.d
        x = point.x.copy()
        x[1:] += zv[B.x[1:]]
        Q = np.zeros((K + 1, d, d))
        Q[1] = D.Q1
        if K > 1:
            Q[2:] = zv[B.Q[2:]]
        S = np.zeros((K + 1, d, d))
        S[1:] = zv[B.S[1:]]
        S[1:] = psd_part(S[1:])
        lam = np.where(B.lam >= 0, zv[np.maximum(B.lam, 0)], 0.0)
        tau = None
        if B.ell is not None:
            from ..allocation import level_for

            tau = level_for(tail(point.tau) * np.exp(zv[B.ell]))
        return Layout(x, Q, S, np.maximum(lam, 0.0), tau)



@dataclass
class ConvexForm:
    """The convexified DOC program at a symbolic point (see module doc).

    z : decision vector (steps, Q, S, lam, auxiliaries; ``layout.blocks``).
    p : parameter vector, the point of linearisation, the split weights and
        alpha (:meth:`StepLayout.params`).
    objective : quadratic in z.
    families : the cone constraints.
    """

    layout: StepLayout
    z: ca.SX
    p: ca.SX
    objective: ca.SX
    families: list[ConeFamily]
    chi2: float


def convex_form(D: ProblemData, chi2_margin: float = 2e-7, proximal: float = 0.0) -> ConvexForm:
    """Build the convexified DOC program of ``D`` symbolically (see module doc).

    chi2_margin : every collision and containment constraint uses
        chi2 (1 + chi2_margin), so that solver rounding never leaves an answer
        on the wrong side of the exact check.
    proximal : eps >= 0 of the proximal term eps/2 (||dx||^2 + ||S - S~||^2 +
        ||lam - lam~||^2) added to the objective (scaled units). It is >= 0 and
        zero at the point, so the step still majorises the cost and its answer
        is monotone and safe; it makes the step strongly convex in the
        directions the cost leaves flat (rank-deficient S, inactive
        certificates), where interior-point solvers otherwise fail
        (docs/numerics.md, "CCP solver cascade").
    """
    K, J, F, d = D.K, D.J, D.F, D.d
    N = D.At.shape[0]
    B = _blocks(D)
    chi2 = D.chi2 * (1.0 + chi2_margin)
    chi2_t = D.chi2_target * (1.0 + chi2_margin)
    z = ca.SX.sym("z", B.n)
    # parameters: the point (x, Q, S, lam) and the split weights
    sizes = [(K + 1) * d, (K + 1) * d * d, (K + 1) * d * d, K * J * F, K * J, K * J]
    if B.ell is not None:
        sizes.append(K * J)                           # the point's levels tau~ (budget mode)
    # the start belief (step_start_values) and alpha: parameters, so one compiled
    # step serves every start and alpha of a (scenario, K)
    sizes.append(step_start_values(D).size)
    sizes.append(1)
    p = ca.SX.sym("p", int(sum(sizes)))
    parts = ca.vertsplit(p, list(np.concatenate([[0], np.cumsum(sizes)]).astype(int)))
    xt = ca.reshape(parts[0], d, K + 1)               # column k = x~_k (row-major ravel -> transposed)
    Qt = [ca.reshape(parts[1][k * d * d:(k + 1) * d * d], d, d).T for k in range(K + 1)]
    St = [ca.reshape(parts[2][k * d * d:(k + 1) * d * d], d, d).T for k in range(K + 1)]
    lamt = ca.reshape(parts[3], F, K * J)             # column k*J + j
    rho_s = parts[4]
    rho_e = parts[5]
    # each pair's level: the fixed chi2, or (budget mode) the majorant of its level
    # tau_kj = h(l_kj) <= aff_kj + 1/2 ||quad_kj||^2 (see _level_majorant), with the margin
    if B.ell is not None:
        aff, quad = _level_majorant(D, B, z, parts[6])
        Lev, Quad = aff * (1.0 + chi2_margin), [qq * np.sqrt(1.0 + chi2_margin) for qq in quad]
    else:
        Lev, Quad = ca.DM.ones(K, J) * chi2, []

    start = ca.vertsplit(parts[-2], list(np.cumsum([0, d, d * d, d * d, 1, d * d, K])))
    x0, Q1, L0s, eps0_sq, T2 = start[0], ca.reshape(start[1], d, d), ca.reshape(start[2], d, d), start[3], \
        ca.reshape(start[4], d, d)
    # each transition's relief off its level (the start's own level chi2_start (1 + chi2_margin)
    # at transition 1, or after a frozen prefix; step_start_values)
    relief = start[5] * (1.0 + chi2_margin)
    X = [x0] + [xt[:, k] + _pick(z, B.x[k][:, None]) for k in range(1, K + 1)]
    Q = [None, Q1] + [_pick(z, B.Q[k]) for k in range(2, K + 1)]
    S = [None] + [_pick(z, B.S[k]) for k in range(1, K + 1)]
    Y = [None] + [Q[k] + S[k] for k in range(1, K + 1)]
    Yt = [None] + [(Q1 if k == 1 else Qt[k]) + St[k] for k in range(1, K + 1)]
    Lam = [[_pick(z, B.lam[0, j][:, None]) for j in range(J)]]      # transition 1 (the exact start end)

    # ------------------------------------------------------------ objective
    control = D.sigma**2 * sum(terms.control(X[k - 1], X[k]) for k in range(1, K + 1))
    Ysym = ca.SX.sym("Y", d, d)
    f_logdet = ca.Function("logdet", [Ysym], [terms.logdet(Ysym)])
    logdet_tangent = tangent(f_logdet)
    concave = sum(logdet_tangent(Yt[k], Y[k]) for k in range(1, K + 1))
    # -log det Q_k: its conic epigraph (u_k); log det Q_1 is a constant
    neg_logdet_q = -sum(ca.sum1(_pick(z, B.u[k][:, None])) for k in range(2, K + 1)) if K > 1 else 0
    alpha = parts[-1]
    objective = control + 0.5 * alpha * (concave + neg_logdet_q)
    if proximal > 0:
        keep = B.lam >= 0
        lam_flat = np.flatnonzero(keep)               # index into point.lam.ravel() (K, J, F)
        dlam = _pick(z, B.lam[keep][:, None]) - parts[3][lam_flat.tolist()]
        dS = [S[k] - St[k] for k in range(1, K + 1)]
        objective = objective + 0.5 * proximal * (ca.sumsqr(_pick(z, B.x[1:].reshape(-1, 1)))
                                                  + sum(ca.sumsqr(e) for e in dS) + ca.sumsqr(dlam))

    fam: list[ConeFamily] = []

    def add(name: str, kind: str, dim: int, items: list, owner: np.ndarray | None = None,
            step: np.ndarray | None = None) -> None:
        if items:
            fam.append(ConeFamily(name, kind, dim, len(items), ca.vertcat(*[ca.vec(e.T) for e in items]), owner,
                                  None if step is None else np.asarray(step, int)))

    lam_idx = B.lam[B.lam >= 0]
    lam_owner = np.nonzero(B.lam >= 0)                 # (k, j, f) of each entry, in lam_idx's order
    fam.append(ConeFamily("lam_nonneg", "nonneg", 1, lam_idx.size, _pick(z, lam_idx[:, None]),
                          lam_owner[0] * J + lam_owner[1]))
    add("sensing_psd", "psd", d, [S[k] for k in range(1, K + 1)], step=np.arange(1, K + 1))
    Winv = ca.DM(np.linalg.inv(D.W))
    add("kalman_lmi", "psd", 2 * d, [terms.kalman_lmi(Q[k], Y[k - 1], Winv) for k in range(2, K + 1)],
        step=np.arange(2, K + 1))
    Zk = {k: _pick(z, B.Z[k]) for k in range(2, K + 1)}
    add("logdet_lmi", "psd", 2 * d, [terms.logdet_epigraph_lmi(Q[k], Zk[k]) for k in range(2, K + 1)],
        step=np.arange(2, K + 1))
    add("logdet_exp", "exp", 3, [ca.vertcat(z[int(B.u[k, i])], 1, Zk[k][i, i])
                                 for k in range(2, K + 1) for i in range(d)], step=np.repeat(np.arange(2, K + 1), d))

    if D.continuous:
        # continuous surrogate: T_k <= (Q_{k-1}^-1 + W)^-1 (the Kalman LMI's form, k >= 3;
        # T_1 = Q_1 and T_2 = (P0 + 2 W)^-1 are constants)
        add("surrogate_lmi", "psd", 2 * d, [terms.kalman_lmi(_pick(z, B.T[k]), Q[k - 1], Winv)
                                            for k in range(3, K + 1)], step=np.arange(3, K + 1))

    # collision constraints: h1 exactly, h2 with the bilinear term convexified;
    # one pair function mapped over every (transition, hazard) end
    pair = _pair_function(d, F, len(Quad))
    first_start = 1 if D.continuous else 2
    for name, ks, end in (("end", np.arange(1, K + 1), True), ("start", np.arange(first_start, K + 1), False)):
        if ks.size == 0:
            continue
        kk = np.repeat(ks, J)                          # transition of each pair
        jj = np.tile(np.arange(J), ks.size)            # hazard of each pair
        kx = kk if end else kk - 1                     # the end's time index
        nb = kk.size
        lam = _pick(z, B.lam[kk - 1, jj].T)            # F x nb
        lt = lamt[:, ((kk - 1) * J + jj).tolist()]
        R = _pick(z, (B.R_end if end else B.R_start)[kk - 1, jj][None, :])
        x = xt[:, kx.tolist()] + _pick(z, B.x[kx].T)
        ky = kk if end else kk - 1                     # information matrix at the end: Q_k or Y_{k-1}
        if D.continuous:                               # both ends: T_k
            Yv = _pick(z, np.concatenate(list(B.T[kk]), axis=1))
            consts = {1: Q1, 2: T2}
            Yc = ca.horzcat(*[consts.get(int(k), ca.SX(d, d)) for k in kk])
        else:
            Yv = _pick(z, np.concatenate(list(B.Q[ky]), axis=1))
            if not end:
                Yv = Yv + _pick(z, np.concatenate(list(B.S[ky]), axis=1))
            Yc = ca.horzcat(*[Q1 if k == 1 else ca.SX(d, d) for k in ky])
        A = ca.DM(np.concatenate(list(D.A[jj]), axis=1))
        b = ca.DM(D.b[jj].T)
        r = ca.sqrt((rho_e if end else rho_s)[((kk - 1) * J + jj).tolist()]).T
        pick = ((kk - 1) * J + jj).tolist()
        lev = ca.vec(Lev.T)[pick].T - relief[(kk - 1).tolist()].T     # the start's transition: its level
        quad = ca.vertcat(*[ca.vec(qq.T)[pick].T for qq in Quad]) if Quad else ca.SX(0, nb)
        h1, h2 = pair.map(nb)(lam, lt, R, x, xt[:, kx.tolist()], Yv + Yc, A, b, r, lev, quad)
        owner = (kk - 1) * J + jj
        fam.append(ConeFamily(f"h1_{name}", "psd", d + 1, nb, ca.vec(h1), owner))
        fam.append(ConeFamily(f"h2_{name}", "soc", d + 2 + len(Quad), nb, ca.vec(h2), owner))
    # k = 1, start end (C8): v^T P0 v <= 2 lam^T (A x0 - b) - chi2, exactly (x0 fixed),
    # as eps0^2 R0 <= 2 lam^T (A x0 - b) - chi2 and R0 >= ||L0^T v / eps0||^2 (an LMI), with
    # P0 = L0 L0^T and eps0 = ||L0||: the LMI's entries are O(1) however small P0 is (the
    # paper's 1e-9 I; a single cone holding v^T P0 v and the O(10) linear part had rows
    # 1.9e4 times apart, docs/numerics.md "Conditioning of the CCP step")
    # (L0 / eps0 and eps0^2 are parameters: step_start_values)
    h2_first, h1_first = [], []
    for j in range(0 if D.continuous else J):       # (continuous: transition 1's start is a generic pair)
        A, b = ca.DM(D.A[j]), ca.DM(D.b[j])
        lam = Lam[0][j]
        R0 = z[int(B.R0[j])]
        w = terms.bilinear(lam, X[0], A, b) - (Lev[0, j] - relief[0]) - eps0_sq * R0
        h2_first.append(_rsoc(w, ca.vertcat(*[qq[0, j] for qq in Quad])) if Quad else w)
        h1_first.append(terms.h1_lmi(R0, ca.mtimes(L0s.T, ca.mtimes(A.T, lam)), ca.DM.eye(d)))
    first = np.arange(len(h2_first))                   # pairs (1, j)
    if Quad:
        add("start_h2", "soc", 2 + len(Quad), h2_first, first)
    elif h2_first:
        add("start_h2", "nonneg", 1, h2_first, first)
    add("start_h1", "psd", d + 1, h1_first, first)
    t1, t2 = [], []
    for n in range(N):
        m1, m2 = terms.target_lmis(X[K], z[int(B.C[n])], Y[K], ca.DM(D.At[n]), D.bt[n], chi2_t)
        t1.append(m1)
        t2.append(m2)
    add("target_face", "psd", 2, t1)
    add("target_shape", "psd", d + 1, t2)
    if B.ell is not None:
        fam.extend(_budget_families(D, B, z, parts[6]))
    return ConvexForm(StepLayout(D, B), z, p, objective, fam, chi2)
