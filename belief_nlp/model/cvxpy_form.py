"""The convexified DOC program (:mod:`.doc`) as one CVXPY problem, compiled once
per (scenario, K) -- alpha is a parameter -- and re-solved with new parameter values.

Nothing here knows the maths. Each cone family of the model is an expression
of z that is affine in z; CasADi's Jacobian splits it into

    entries = M z + Srow (c(p) * z[cols]) + e + Soff o(p)

with M, e constant (scenario data) and c(p), o(p) the coefficients and
offsets that depend on the point of linearisation. In CVXPY, c and o are two
Parameter vectors entering as ``cp.multiply(c, z[cols])`` (DPP), every family
is ONE batched constraint ((B, n, n) PSD, SOC along axis 1, exponential
cones, nonnegativity), so the compile is about ten constraint objects
whatever K is. One generated CasADi function maps a point to all parameter
values. Measured figures: docs/numerics.md, "CVXPY subproblem".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .data import Layout
from .doc import ConvexForm, StepLayout

__all__ = ["AffineSplit", "split_affine", "QuadraticSplit", "split_objective", "CompiledProblem", "compile_problem", "usable_solvers"]


@dataclass
class AffineSplit:
    """entries(z, p) = M z + e + scatter(c(p) * z[cols]) + scatter(o(p))."""

    m: int
    M: sp.csr_matrix
    e: np.ndarray
    p_rows: np.ndarray      # row of each parameter coefficient
    p_cols: np.ndarray      # column (z index) of each parameter coefficient
    p_coef: ca.SX           # (n_p,) coefficient expressions of p
    o_rows: np.ndarray      # rows whose offset depends on p
    o_expr: ca.SX           # (n_o,) offset expressions of p


def _param_rows(v: ca.SX, p: ca.SX) -> np.ndarray:
    """Which entries of v depend on p (structurally, from CasADi's Jacobian sparsity)."""
    # the sparsity alone (no derivative expressions: a third of a step's build time before)
    rows = np.asarray(ca.jacobian_sparsity(v, p).get_triplet()[0], dtype=int)
    mask = np.zeros(int(v.numel()), dtype=bool)
    mask[rows] = True
    return mask


def split_affine(expr: ca.SX, z: ca.SX, p: ca.SX) -> AffineSplit:
    """Split an expression affine in z into constant and parameter parts."""
    m = int(expr.numel())
    n = int(z.numel())
    J = ca.jacobian(expr, z)
    if ca.depends_on(J, z):
        raise ValueError("the model expression is not affine in the decision vector")
    rows, cols = (np.asarray(a, dtype=int) for a in J.sparsity().get_triplet())
    nz = J.nz[:]
    off = ca.substitute(expr, z, ca.DM.zeros(n))
    dep_c = _param_rows(nz, p)
    dep_o = _param_rows(off, p)
    # constant parts: evaluated at any p (they do not depend on it)
    vals = ca.Function("c", [p], [nz])(np.ones(p.numel())).full().ravel() if nz.numel() else np.zeros(0)
    e = ca.Function("o", [p], [off])(np.ones(p.numel())).full().ravel()
    keep = ~dep_c
    M = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(m, n))
    e = np.where(dep_o, 0.0, e)
    pidx = np.nonzero(dep_c)[0]
    oidx = np.nonzero(dep_o)[0]
    return AffineSplit(m, M, e, rows[pidx], cols[pidx], nz[pidx.tolist()] if pidx.size else ca.SX(0, 1),
                       oidx, off[oidx.tolist()] if oidx.size else ca.SX(0, 1))


@dataclass
class QuadraticSplit:
    """objective(z, p) = 1/2 z^T H z + q0^T z + q(p)[q_rows]^T z (+ a constant)."""

    H: sp.csr_matrix        # (n, n) symmetric, constant
    q0: np.ndarray          # (n,) the constant part of the linear term (0 on q_rows)
    q_rows: np.ndarray      # entries of the linear term that depend on p
    q_expr: ca.SX           # their expressions of p


def split_objective(objective: ca.SX, z: ca.SX, p: ca.SX) -> QuadraticSplit:
    """Split an objective quadratic in z with constant curvature (the CCP step's)."""
    n = int(z.numel())
    H = ca.hessian(objective, z)[0]
    if ca.depends_on(H, p) or ca.depends_on(H, z):
        raise ValueError("the model objective must be quadratic in z with constant curvature")
    Hs = ca.evalf(H)
    hr, hc = (np.asarray(a, dtype=int) for a in Hs.sparsity().get_triplet())
    grad = ca.substitute(ca.gradient(objective, z), z, ca.DM.zeros(n))
    dep = _param_rows(grad, p)
    q0 = np.where(dep, 0.0, ca.Function("q0", [p], [grad])(np.ones(p.numel())).full().ravel())
    q_rows = np.nonzero(dep)[0]
    return QuadraticSplit(sp.csr_matrix((np.array(Hs.nonzeros()), (hr, hc)), shape=(n, n)), q0, q_rows,
                          grad[q_rows.tolist()])


@dataclass
class CompiledProblem:
    """The CVXPY problem of one convex form, with the map point -> parameters.

    problem : the ``cvxpy.Problem`` (DPP; parameters set by :meth:`set_point`).
    z : its ``cvxpy.Variable`` (the model's decision vector, scaled units).
    x_ref : Parameter (K+1, d), the current means (scaled): the means of the
        step's answer are ``x_ref + dx`` (see :meth:`means`).
    constraints : {family name: cvxpy constraint}; ``user`` holds the
        constraints a user added (:meth:`with_constraints`).
    layout : where the model's quantities sit in z (numbers only).
    """

    layout: StepLayout
    problem: object
    z: object
    x_ref: object
    constraints: dict
    coef_params: list
    coef_fn: ca.Function
    sizes: list
    objective: object = None
    user: list = field(default_factory=list)

    def __getstate__(self) -> dict:
        # the solver object CVXPY keeps for warm starts does not pickle (and a
        # fresh one costs nothing: Clarabel has no warm start); the compiled
        # parameter map in problem._cache is what a disk entry is for
        if hasattr(self.problem, "_solver_cache"):
            self.problem._solver_cache = {}
        return dict(self.__dict__)

    def set_point(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray) -> None:
        """Set every parameter for the convexification at ``point``."""
        pv = self.layout.params(point, rho_start, rho_end)
        vals = self.coef_fn(pv).full().ravel()
        pos = 0
        for par, size in zip(self.coef_params, self.sizes):
            par.value = vals[pos:pos + size]
            pos += size
        self.x_ref.value = point.x

    def means(self):
        """The step's means as a CVXPY expression (K+1, d) in metres (row 0 = x0)."""
        import cvxpy as cp

        B, D = self.layout.blocks, self.layout.data
        K, d = D.K, D.d
        rows = np.arange(d, (K + 1) * d)                       # row 0 (x0) has no step variable
        sel = sp.csr_matrix((np.ones(rows.size), (rows, B.x[1:].ravel())), shape=((K + 1) * d, B.n))
        dx = cp.reshape(sel @ self.z, (K + 1, d), order="C")
        return D.sigma * (self.x_ref + dx)

    def with_constraints(self, constraints: list) -> "CompiledProblem":
        """A copy whose problem also holds ``constraints`` (CVXPY constraints on
        :meth:`means`, ``z`` or your own variables; compiled again once)."""
        import cvxpy as cp

        user = self.user + list(constraints)
        prob = cp.Problem(self.objective, list(self.constraints.values()) + user)
        if not prob.is_dcp():
            raise ValueError("the added constraints are not convex (DCP)")
        return CompiledProblem(self.layout, prob, self.z, self.x_ref, self.constraints, self.coef_params,
                               self.coef_fn, self.sizes, self.objective, user)


class _Params:
    """The CVXPY Parameters of a problem and the map from a point to their values.

    Coefficients that are proportional as functions of p (the same tangent
    entry in two rows, sqrt(rho) times each face normal, ...) share one
    Parameter entry times a constant: CVXPY's compiled tensor has a column per
    Parameter entry, so this keeps the compile small. Proportionality is found
    by evaluating the expressions at a few random points (two functions of p
    that agree in ratio at three random points are proportional unless by a
    coincidence of measure zero)."""

    def __init__(self, p: ca.SX, n_probes: int = 3, seed: int = 0):
        self.p = p
        rng = np.random.default_rng(seed)
        self.probes = rng.uniform(0.5, 1.5, size=(int(p.numel()), n_probes))
        self.params: list = []
        self.outputs: list = []
        self.sizes: list = []

    def vector(self, cp, exprs: ca.SX):
        """A CVXPY expression (len(exprs),) equal to ``exprs`` at the point set."""
        f = ca.Function("probe", [self.p], [exprs])
        V = np.column_stack([f(self.probes[:, i]).full().ravel() for i in range(self.probes.shape[1])])
        base = V[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.where(base[:, None] != 0, V / base[:, None], V)
        keys = np.round(ratios, 9)
        own = base == 0                               # no common scale: a parameter of its own
        keys[own] = np.nan
        keys = np.column_stack([keys, np.where(own, np.arange(V.shape[0]), -1)])
        keys = np.nan_to_num(keys, nan=np.inf)
        _, first, gid = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        gid = gid.ravel()
        reps = first
        n_groups = first.size
        kappa = np.where(own, 1.0, base / np.where(base[reps[gid]] != 0, base[reps[gid]], 1.0))
        theta = cp.Parameter(n_groups)
        self.params.append(theta)
        self.outputs.append(exprs[reps.tolist()])
        self.sizes.append(n_groups)
        if np.allclose(kappa, 1.0) and n_groups == V.shape[0] and np.array_equal(gid, np.arange(n_groups)):
            return theta
        return cp.multiply(kappa, theta[gid])

    def function(self) -> ca.Function:
        return ca.Function("ccp_parameters", [self.p], [ca.vertcat(*self.outputs)])


def _affine_cvx(cp, z, split: AffineSplit, params: _Params):
    expr = split.M @ z + split.e
    if split.p_rows.size:
        c = params.vector(cp, split.p_coef)
        scatter = sp.csr_matrix((np.ones(split.p_rows.size), (split.p_rows, np.arange(split.p_rows.size))),
                                shape=(split.m, split.p_rows.size))
        expr = expr + scatter @ cp.multiply(c, z[split.p_cols])
    if split.o_rows.size:
        o = params.vector(cp, split.o_expr)
        scatter = sp.csr_matrix((np.ones(split.o_rows.size), (split.o_rows, np.arange(split.o_rows.size))),
                                shape=(split.m, split.o_rows.size))
        expr = expr + scatter @ o
    return expr


def _square_root(H: sp.csr_matrix) -> sp.csr_matrix:
    """F with F^T F = H (H symmetric PSD), block diagonal like H: one dense
    eigen-decomposition per connected block of H's sparsity (the means' control
    term couples neighbouring steps; a proximal term is diagonal), so F stays
    as sparse as H and the solver's quadratic data with it."""
    from scipy.sparse.csgraph import connected_components

    n_blocks, label = connected_components(H, directed=False)
    rows, cols, vals = [], [], []
    Hd = H.tocsr()
    for b in range(n_blocks):
        idx = np.flatnonzero(label == b)
        w, V = np.linalg.eigh(Hd[idx][:, idx].toarray())
        Fb = (V * np.sqrt(np.maximum(w, 0.0))).T
        r, c = np.nonzero(Fb)
        rows.append(idx[r])
        cols.append(idx[c])
        vals.append(Fb[r, c])
    n = H.shape[0]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def compile_problem(form: ConvexForm) -> CompiledProblem:
    """Build the CVXPY problem of ``form`` (the canonicalisation happens at the
    first solve and is cached by CVXPY)."""
    import cvxpy as cp

    n = form.layout.blocks.n
    z = cp.Variable(n, name="z")
    params = _Params(form.p)
    cons = {}
    for fam in form.families:
        E = _affine_cvx(cp, z, split_affine(fam.expr, form.z, form.p), params)
        if fam.kind == "nonneg":
            cons[fam.name] = cp.constraints.NonNeg(E)
        elif fam.kind == "psd":
            cons[fam.name] = cp.constraints.PSD(cp.reshape(E, (fam.batch, fam.dim, fam.dim), order="C"))
        elif fam.kind == "soc":
            E2 = cp.reshape(E, (fam.batch, fam.dim), order="C")
            cons[fam.name] = cp.SOC(E2[:, 0], E2[:, 1:], axis=1)
        elif fam.kind == "exp":
            E2 = cp.reshape(E, (fam.batch, 3), order="C")
            cons[fam.name] = cp.constraints.ExpCone(E2[:, 0], E2[:, 1], E2[:, 2])
        else:  # pragma: no cover - the model only makes the kinds above
            raise ValueError(f"unknown cone kind {fam.kind!r}")
    # objective: 1/2 z^T H z (constant H) + q(p)^T z
    quad = split_objective(form.objective, form.z, form.p)
    act = np.unique(quad.H.indices)                       # variables with curvature (the means)
    Fq = _square_root(quad.H[act][:, act])
    obj = 0.5 * cp.sum_squares(Fq @ z[act]) + quad.q0 @ z + params.vector(cp, quad.q_expr) @ z[quad.q_rows]
    objective = cp.Minimize(obj)
    problem = cp.Problem(objective, list(cons.values()))
    x_ref = cp.Parameter((form.layout.data.K + 1, form.layout.data.d), name="x_ref")
    return CompiledProblem(form.layout, problem, z, x_ref, cons, params.params, params.function(), params.sizes,
                           objective)


def usable_solvers() -> list[str]:
    """Installed CVXPY solvers that take PSD and exponential cones (the CCP step needs both)."""
    import cvxpy as cp
    from cvxpy.reductions.solvers.defines import SOLVER_MAP_CONIC

    out = []
    for name in cp.installed_solvers():
        s = SOLVER_MAP_CONIC.get(name)
        if s is None:
            continue
        kinds = {c.__name__ for c in s.SUPPORTED_CONSTRAINTS}
        if {"SOC", "ExpCone"} <= kinds and kinds & {"PSD", "SvecPSD"}:
            out.append(name)
    return out
