"""The convexified DOC program (:mod:`.doc`) as one CVXPY problem, compiled once
per (scenario, K, alpha) and re-solved with new parameter values.

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

__all__ = ["AffineSplit", "split_affine", "CompiledProblem", "compile_problem"]


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
    rows = np.asarray(ca.jacobian(v, p).sparsity().get_triplet()[0], dtype=int)
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
    vals = np.asarray(ca.Function("c", [p], [nz, off])(np.ones(p.numel()))[0]).ravel() if nz.numel() else np.zeros(0)
    e = np.asarray(ca.Function("o", [p], [off])(np.ones(p.numel()))).ravel()
    keep = ~dep_c
    M = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(m, n))
    e = np.where(dep_o, 0.0, e)
    pidx = np.nonzero(dep_c)[0]
    oidx = np.nonzero(dep_o)[0]
    return AffineSplit(m, M, e, rows[pidx], cols[pidx], nz[pidx.tolist()] if pidx.size else ca.SX(0, 1),
                       oidx, off[oidx.tolist()] if oidx.size else ca.SX(0, 1))


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
        vals = np.asarray(self.coef_fn(pv)).ravel()
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
        sel = np.zeros(((K + 1) * d, B.n))
        rows = np.arange(d, (K + 1) * d)
        sel[rows, B.x[1:].ravel()] = 1.0
        dx = cp.reshape(sp.csr_matrix(sel) @ self.z, (K + 1, d), order="C")
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


def _affine_cvx(cp, z, split: AffineSplit, params: list, outputs: list, sizes: list):
    expr = split.M @ z + split.e
    if split.p_rows.size:
        c = cp.Parameter(split.p_rows.size)
        scatter = sp.csr_matrix((np.ones(split.p_rows.size), (split.p_rows, np.arange(split.p_rows.size))),
                                shape=(split.m, split.p_rows.size))
        expr = expr + scatter @ cp.multiply(c, z[split.p_cols])
        params.append(c)
        outputs.append(split.p_coef)
        sizes.append(split.p_rows.size)
    if split.o_rows.size:
        o = cp.Parameter(split.o_rows.size)
        scatter = sp.csr_matrix((np.ones(split.o_rows.size), (split.o_rows, np.arange(split.o_rows.size))),
                                shape=(split.m, split.o_rows.size))
        expr = expr + scatter @ o
        params.append(o)
        outputs.append(split.o_expr)
        sizes.append(split.o_rows.size)
    return expr


def compile_problem(form: ConvexForm) -> CompiledProblem:
    """Build the CVXPY problem of ``form`` (the canonicalisation happens at the
    first solve and is cached by CVXPY)."""
    import cvxpy as cp

    n = form.layout.blocks.n
    z = cp.Variable(n, name="z")
    params: list = []
    outputs: list = []
    sizes: list = []
    cons = {}
    for fam in form.families:
        E = _affine_cvx(cp, z, split_affine(fam.expr, form.z, form.p), params, outputs, sizes)
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
    H = ca.hessian(form.objective, form.z)[0]
    if ca.depends_on(H, form.p) or ca.depends_on(H, form.z):
        raise ValueError("the model objective must be quadratic in z with constant curvature")
    Hd = np.asarray(ca.evalf(H))
    act = np.nonzero(np.any(Hd != 0, axis=1))[0]
    w, V = np.linalg.eigh(Hd[np.ix_(act, act)])
    Fq = (V * np.sqrt(np.maximum(w, 0.0))).T
    grad = ca.substitute(ca.gradient(form.objective, form.z), form.z, ca.DM.zeros(n))
    q = cp.Parameter(n, name="q")
    params.append(q)
    outputs.append(grad)
    sizes.append(n)
    obj = 0.5 * cp.sum_squares(Fq @ z[act]) + q @ z
    objective = cp.Minimize(obj)
    problem = cp.Problem(objective, list(cons.values()))
    coef_fn = ca.Function("ccp_parameters", [form.p], [ca.vertcat(*outputs)])
    x_ref = cp.Parameter((form.layout.data.K + 1, form.layout.data.d), name="x_ref")
    return CompiledProblem(form.layout, problem, z, x_ref, cons, params, coef_fn, sizes, objective)
