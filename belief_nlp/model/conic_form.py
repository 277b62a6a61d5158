"""The convexified DOC program (:mod:`.doc`) as Clarabel's own conic data, for
the active-set step: only the (transition, hazard) pairs near their bound.

Generated from the same :class:`.doc.ConvexForm` as the CVXPY problem
(:mod:`.cvxpy_form`), with the same affine split of every cone family
(:func:`.cvxpy_form.split_affine`); tests hold the two equal. Clarabel's form
is  min 1/2 z^T P z + q^T z  s.t.  A z + s = b, s in K: a family's entries
E = G(p) z + h(p) give s = T E, A = -T G, b = T h, with T the identity except
for PSD cones, where it maps the full n x n matrix to Clarabel's scaled upper
triangle (column by column, off-diagonals (E_ij + E_ji) / sqrt 2).

Why: a CCP step's cost is the interior-point solve, ~18 us per pair end per
iteration (docs/numerics.md), and most pairs are far from their bound: on
paper-multi at K = 20 about 10 % of the 200 pairs are within 3 chi2. Leaving
the others out (their certificate variables fixed at the point) keeps the
step a majorant of the cost with the point feasible, so its answer never
raises the cost; the exact check decides safety as for every answer, and a
refused answer sends the step to the full problem (methods/ccp.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..errors import solver_panicked
from .cones import KINDS
from .data import Layout
from .doc import ConvexForm, StepLayout
from .cvxpy_form import split_affine, split_objective

__all__ = ["ConicStep", "conic_step"]

_S2 = np.sqrt(2.0)


def _svec_map(n: int) -> tuple[np.ndarray, np.ndarray, int]:
    """For the n x n entries (row-major): the row of Clarabel's scaled upper
    triangle each maps to and its weight; and the triangle's length."""
    row = np.empty((n, n), dtype=int)
    w = np.empty((n, n))
    pos = 0
    for j in range(n):                 # column by column, upper triangle
        for i in range(j + 1):
            row[i, j] = row[j, i] = pos
            w[i, j] = w[j, i] = 1.0 if i == j else 1.0 / _S2     # (E_ij + E_ji) / 2 * sqrt 2
            pos += 1
    return row.ravel(), w.ravel(), pos


@dataclass
class ConicStep:
    """The step's data with every parameter-dependent entry at known positions.

    A (m, n) CSC: ``A.data = bincount(a_slot, a_const + a_weight * coef(p))``;
    b = bincount(b_row, b_const + b_weight * offset(p)); q = q0 + scatter(q(p)).
    ``cones``: (kind, dim, first row, rows, owner pair, step of a cone of no
    pair or -1: :attr:`.cones.ConeFamily.step`); ``col_owner``: the pair each
    variable belongs to (-1: none)."""

    layout: StepLayout
    P: sp.csc_matrix
    q0: np.ndarray
    q_rows: np.ndarray
    A_shape: tuple
    A_indices: np.ndarray
    A_indptr: np.ndarray
    a_slot: np.ndarray
    a_const: np.ndarray
    a_weight: np.ndarray
    b_row: np.ndarray
    b_const: np.ndarray
    b_weight: np.ndarray
    fn: ca.Function
    cones: list
    col_owner: np.ndarray

    def data(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray):
        """(A, b, q) of the step linearised at ``point``."""
        pv = self.layout.params(point, rho_start, rho_end)
        out = self.fn(pv)
        coef, off, qv = (np.asarray(v, float).ravel() for v in out)
        n_slots = self.A_indices.size
        vals = np.concatenate([self.a_const, self.a_weight * coef])
        A = sp.csc_matrix((np.bincount(self.a_slot, vals, minlength=n_slots), self.A_indices, self.A_indptr),
                          shape=self.A_shape)
        # entries whose coefficient is 0 at this point (certificates at 0, a start
        # factor's zeros) leave the pattern: Clarabel's KKT system then depends on
        # the values only, not on which entries the symbolic form could fill
        A.eliminate_zeros()
        bvals = np.concatenate([self.b_const, self.b_weight * off])
        b = np.bincount(self.b_row, bvals, minlength=self.A_shape[0])
        q = self.q0.copy()
        q[self.q_rows] += qv
        return A, b, q

    def solve(self, point: Layout, rho_start: np.ndarray, rho_end: np.ndarray, keep: np.ndarray,
              settings: dict | None = None, time_left: float | None = None,
              frozen: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[str, np.ndarray | None, float, int]:
        """Solve with only the pairs ``keep`` (bool, K x J flattened as k * J + j)
        and the cones of no pair; the other pairs' variables stay at the point's
        values (:meth:`StepLayout.point_vector`). ``frozen``: (variables, cones)
        masks also held at the point and left out (a frozen prefix,
        :mod:`.conic_prefix`). Returns (status in CVXPY's words, z or None,
        solve time, iterations)."""
        import clarabel

        A, b, q = self.data(point, rho_start, rho_end)
        zp = self.layout.point_vector(point)
        keep = np.asarray(keep, bool).ravel()
        free = (self.col_owner < 0) | keep[np.maximum(self.col_owner, 0)]
        kind, dim, first, n_rows, owner, _ = self.cones
        on = (owner < 0) | keep[np.maximum(owner, 0)]
        if frozen is not None:
            free, on = free & ~frozen[0], on & ~frozen[1]
        rows = np.repeat(first[on] - np.cumsum(n_rows[on]) + n_rows[on], n_rows[on]) + np.arange(n_rows[on].sum())
        Ar = A.tocsr()[rows]
        fixed = ~free
        b_red = b[rows] - Ar[:, fixed] @ zp[fixed]
        A_red = Ar[:, free].tocsc()
        Pf = self.P[:, free]
        P_red = Pf[free].tocsc()
        q_red = q[free] + (Pf[fixed].T + self.P[free][:, fixed]) @ zp[fixed]
        st = clarabel.DefaultSettings()
        st.verbose = False
        for k, v in (settings or {}).items():
            setattr(st, k, v)
        if time_left is not None:
            st.time_limit = max(float(time_left), 1e-3)
        t0 = time.perf_counter()
        try:
            sol = clarabel.DefaultSolver(P_red, q_red, A_red, b_red, _cones(clarabel, kind[on], dim[on]), st).solve()
        except (ValueError, RuntimeError, ArithmeticError) as exc:
            return f"error: {str(exc).splitlines()[0][:120]}", None, time.perf_counter() - t0, 0
        except BaseException as exc:       # a Rust panic is a failed solve (the cascade goes on), not a crash
            if not solver_panicked(exc):
                raise
            return f"error: solver panicked ({str(exc)[:100]})", None, time.perf_counter() - t0, 0
        # InsufficientProgress with a point is an inaccurate answer, as the CVXPY entries take it
        # (methods.ccp_cascade.ACCEPT_UNKNOWN): the exact check and the monotone test decide
        status = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate",
                  "InsufficientProgress": "optimal_inaccurate"}.get(str(sol.status), str(sol.status))
        if status not in ("optimal", "optimal_inaccurate") or not np.all(np.isfinite(sol.x)):
            return status, None, float(sol.solve_time), int(sol.iterations)
        z = zp.copy()
        z[free] = np.asarray(sol.x, float)
        return status, z, float(sol.solve_time), int(sol.iterations)


def _cones(clarabel, kinds: np.ndarray, dims: np.ndarray) -> list:
    """Clarabel's cone objects (kind codes: index in :data:`.cones.KINDS`);
    runs of 1-row nonnegative cones become one (Clarabel's work is per cone object)."""
    out, run = [], 0
    for kind, dim in zip(kinds.tolist(), dims.tolist()):
        if kind == 0:
            run += 1
            continue
        if run:
            out.append(clarabel.NonnegativeConeT(run))
            run = 0
        out.append(clarabel.PSDTriangleConeT(dim) if kind == 1 else
                   clarabel.SecondOrderConeT(dim) if kind == 2 else clarabel.ExponentialConeT())
    if run:
        out.append(clarabel.NonnegativeConeT(run))
    return out


def conic_step(form: ConvexForm) -> ConicStep:
    """Clarabel's data of ``form`` (see the module doc)."""
    B = form.layout.blocks
    n = B.n
    a_r, a_c, a_v, p_r, p_c, p_w, coefs = [], [], [], [], [], [], []
    b_r, b_v, o_r, o_w, offs = [], [], [], [], []
    kinds, dims, firsts, counts, owners, steps = [], [], [], [], [], []
    row0 = 0
    for fam in form.families:
        split = split_affine(fam.expr, form.z, form.p)
        idx = np.arange(split.m)
        if fam.kind == "psd":
            srow1, w1, per_cone = _svec_map(fam.dim)
            per = fam.dim * fam.dim
            srow, wt = row0 + (idx // per) * per_cone + srow1[idx % per], w1[idx % per]
        else:
            per_cone = fam.dim
            srow, wt = row0 + idx, np.ones(split.m)
        Mc = split.M.tocoo()
        a_r.append(srow[Mc.row]), a_c.append(Mc.col), a_v.append(-wt[Mc.row] * Mc.data)
        p_r.append(srow[split.p_rows]), p_c.append(split.p_cols), p_w.append(-wt[split.p_rows])
        coefs.append(split.p_coef)
        b_r.append(srow), b_v.append(wt * split.e)
        o_r.append(srow[split.o_rows]), o_w.append(wt[split.o_rows])
        offs.append(split.o_expr)
        kinds.append(np.full(fam.batch, KINDS.index(fam.kind)))
        dims.append(np.full(fam.batch, fam.dim))
        firsts.append(row0 + np.arange(fam.batch) * per_cone)
        counts.append(np.full(fam.batch, per_cone))
        owners.append(np.full(fam.batch, -1) if fam.owner is None else np.asarray(fam.owner, int))
        steps.append(np.full(fam.batch, -1) if fam.step is None else np.asarray(fam.step, int))
        row0 += fam.batch * per_cone
    m = row0
    rows = np.concatenate(a_r + p_r)
    cols = np.concatenate(a_c + p_c)
    key, slot = np.unique(cols.astype(np.int64) * m + rows, return_inverse=True)
    indptr = np.searchsorted(key // m, np.arange(n + 1)).astype(np.int64)
    quad = split_objective(form.objective, form.z, form.p)
    P = sp.triu(quad.H).tocsc()
    fn = ca.Function("conic_step", [form.p], [ca.vertcat(*coefs), ca.vertcat(*offs), quad.q_expr])
    return ConicStep(form.layout, P, quad.q0, quad.q_rows, (m, n), (key % m).astype(np.int64), indptr, slot.ravel(),
                     np.concatenate(a_v), np.concatenate(p_w), np.concatenate(b_r + o_r),
                     np.concatenate(b_v), np.concatenate(o_w), fn,
                     [np.concatenate(a) for a in (kinds, dims, firsts, counts, owners, steps)],
                     form.layout.variable_owners())


