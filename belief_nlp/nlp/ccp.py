"""The convex-concave procedure (paper section IV.A) for the smoothing model.

Each iteration linearises the concave parts at the current point -- the
gradient of log det Y_k and of the collision split, both from the CasADi
model -- and solves the convex conic subproblem (conic.py). The subproblem's
sparsity is fixed, so the data is assembled once per iteration with numpy and
the Clarabel solver object is reused through its data-update interface when
the installed Clarabel allows it.

Guarantees kept in the loop:
* every accepted iterate passes the exact continuous-time safety check
  (geometry.transition_clearances) and target containment;
* the cost never increases: a step that would raise it by more than
  ``monotone_tol`` (relative) is rejected and the loop stops with status
  "non_monotone";
* a failed subproblem is retried once with other settings (equilibration
  on, more iterations, more regularisation); a second failure returns the
  best iterate with status "solver_failed";
* solver tolerance can leave an answer infeasible by ~1e-7; such an iterate
  is repaired by a uniform dose of extra sensing and checked again.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..geometry import PolytopeSet, transition_minimiser
from ..scenario import Scenario
from .conic import ConicSubproblem
from .model import BeliefModel, Layout
from .result import STATUSES, IterationRecord, SmoothResult
from .warmstart import WarmStart

__all__ = ["ccp"]

log = logging.getLogger("belief_nlp.smoother")

_SOLVED = {"Solved", "AlmostSolved"}


def _clarabel_settings(options: dict, safe: bool):
    """Clarabel settings for the CCP subproblems.

    Equilibration is off by default: on paper-multi (K = 5..20, alpha 0.1
    and 1) Clarabel's default equilibration ended 65 of 174 subproblems in
    InsufficientProgress, without it 0 of 110 failed. The retry ("safe")
    turns it back on with more iterations and stronger regularisation --
    a different path through the same problem.
    """
    import clarabel

    st = clarabel.DefaultSettings()
    st.verbose = False
    st.presolve_enable = False          # keeps the data-update path available
    st.equilibrate_enable = False
    if safe:
        st.equilibrate_enable = True
        st.max_iter = 400
        st.static_regularization_constant = 1e-7
    for k, v in options.items():        # user settings win
        if not hasattr(st, k):
            raise ValueError(f"unknown Clarabel setting {k!r}")
        setattr(st, k, v)
    return st


class _ClarabelRunner:
    """Owns the Clarabel solver; updates its data in place when allowed."""

    def __init__(self, options: dict):
        import clarabel

        self.cl = clarabel
        self.options = dict(options)
        self.solver = None
        self.safe = False

    def solve(self, data, safe: bool = False) -> tuple[str, np.ndarray | None, float, int]:
        cl = self.cl
        if self.solver is None or safe != self.safe:
            self.solver = cl.DefaultSolver(data.P, data.q, data.A, data.b, data.cones,
                                           _clarabel_settings(self.options, safe))
            self.safe = safe
        else:
            try:
                self.solver.update(q=data.q, A=data.A, b=data.b)
            except Exception:  # pragma: no cover - older Clarabel or pattern change
                self.solver = cl.DefaultSolver(data.P, data.q, data.A, data.b, data.cones,
                                               _clarabel_settings(self.options, safe))
        sol = self.solver.solve()
        status = str(sol.status)
        x = np.asarray(sol.x) if status in _SOLVED else None
        return status, x, float(sol.solve_time), int(sol.iterations)


def _cvxpy_solve(data, solver: str, options: dict) -> tuple[str, np.ndarray | None, float, int]:
    """Solve the same conic data with another conic solver through CVXPY.

    The conic rows are handed over as they are (one CVXPY constraint per
    cone of ``data.spec``), so there is no second copy of the model."""
    import cvxpy as cp

    z = cp.Variable(data.A.shape[1])
    A = data.A.tocsr()
    cons = []
    row = 0
    for kind, n, m in data.spec:
        s = data.b[row:row + m] - A[row:row + m] @ z
        if kind == "psd":
            cons.append(_smat(s, n) >> 0)
        elif kind == "soc":
            cons.append(cp.SOC(s[0], s[1:]))
        elif kind == "nonneg":
            cons.append(s >= 0)
        else:
            cons.append(cp.constraints.ExpCone(s[0], s[1], s[2]))
        row += m
    Pfull = (data.P + data.P.T - sp.diags(data.P.diagonal())).tocsc()
    prob = cp.Problem(cp.Minimize(0.5 * cp.quad_form(z, cp.psd_wrap(Pfull)) + data.q @ z), cons)
    t0 = time.perf_counter()
    try:
        prob.solve(solver=solver, **options)
    except cp.error.SolverError as exc:
        return f"SolverError: {exc}", None, time.perf_counter() - t0, 0
    ok = prob.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
    st = prob.solver_stats
    return ("Solved" if ok else str(prob.status)), (np.asarray(z.value) if ok else None), \
        float(st.solve_time or (time.perf_counter() - t0)), int(st.num_iters or 0)


def _smat(s, n):
    """CVXPY symmetric matrix from Clarabel's scaled upper-triangle vector."""
    import cvxpy as cp

    idx = {}
    p = 0
    for j in range(n):
        for i in range(j + 1):
            idx[(i, j)] = p
            p += 1
    rows = []
    for i in range(n):
        row = []
        for j in range(n):
            a, b = min(i, j), max(i, j)
            row.append((1.0 if a == b else 1.0 / np.sqrt(2.0)) * s[idx[(a, b)]])
        rows.append(cp.hstack(row))
    return cp.vstack(rows)


def _pair_vectors(model: BeliefModel, z: Layout) -> np.ndarray:
    """v_{k,j} = A_j^T lam_{k,j}, (K, J, d)."""
    return np.einsum("jfd,kjf->kjd", model.data.A, z.lam)


def _check_and_repair(model: BeliefModel, z: Layout, hazards: PolytopeSet) -> tuple[Layout, float]:
    """Exact safety check of an iterate; repair certificates the solver left
    slightly infeasible.

    Returns the iterate -- with lam of every (transition, hazard) pair whose
    Lemma-1 end conditions fail (solver tolerance) replaced by the scaled
    Theorem-1 certificate of its own tight covariances -- and the smallest
    exact clearance dist2 - chi2 over all pairs (>= 0 is safe). The solver's
    own lambdas are kept elsewhere: they are well scaled for the next
    subproblem, unlike margin-maximising ones."""
    from .warmstart import certificates

    D = model.data
    path = model.to_path(z)
    tm = transition_minimiser(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise, hazards)
    start, end = model.transition_margins(z)
    bad = (start < 0) | (end < 0)
    out = z.copy()
    if np.any(bad):
        lam = certificates(model.scenario, path, hazards) * D.sigma
        out.lam = np.where(bad[..., None], lam, z.lam)
    return out, float(np.min(tm.dist2) - D.chi2)


def initial_rho(model: BeliefModel, z: Layout) -> np.ndarray:
    """Split weights rho_{k,j} (K, J) for the first subproblem.

    The majorant error 1/2 ||sqrt(rho) dv - dx / sqrt(rho)||^2 is smallest for
    rho = ||dx|| / ||dv||; before any step, take the mean step length for
    ||dx|| and ||v~|| for ||dv|| (a certificate can change by its own size)."""
    steps = np.linalg.norm(np.diff(z.x, axis=0), axis=1)
    step_scale = max(float(np.mean(steps)), 1e-3)
    vnorm = np.linalg.norm(_pair_vectors(model, z), axis=-1)
    return step_scale / np.maximum(vnorm, 1e-6)


def _repair(model: BeliefModel, z: Layout, hazards: PolytopeSet, deficit: float) -> tuple[Layout, float, float] | None:
    """Restore exact feasibility lost to solver tolerance (violations ~1e-7).

    Adds sensing eta * Y_k at every step k >= 1 (every posterior shrinks by
    1 / (1 + eta)) and re-derives the priors (Lemma 2): all ellipses of every
    transition but the first shrink, so clearances and target margins grow,
    at an information cost of about alpha/2 * K * d * eta. Tries eta from
    10x the deficit upward; returns (iterate, clearance margin, target margin)
    or None."""
    eta = max(10 * deficit, 1e-9)
    for _ in range(6):
        cand = z.copy()
        cand.S[1:] = cand.S[1:] + eta * z.Y[1:]
        cand = model.tighten(cand)
        cand, margin = _check_and_repair(model, cand, hazards)
        tgt = float(np.min(model.target_margins(cand)))
        if margin >= 0 and tgt >= 0:
            return cand, margin, tgt
        eta *= 10
        if eta > 1e-3:
            break
    return None


def ccp(scenario: Scenario, start: WarmStart, *, alpha: float | None = None, max_iter: int = 50,
        tol: float = 1e-4, solver: str = "CLARABEL", solver_options: dict | None = None,
        time_limit: float | None = None, monotone_tol: float = 1e-7, keep_iterates: bool = False,
        rho: float | None = None, progress: bool = False, _fail_at: int | None = None) -> SmoothResult:
    """Run CCP from a warm start. Use :func:`belief_nlp.smooth` rather than this."""
    t_start = time.perf_counter()
    solver_options = dict(solver_options or {})
    K = start.K
    model = BeliefModel(scenario, K, alpha)
    D = model.data
    hazards = PolytopeSet.build(scenario.hazards)
    z = model.tighten(model.from_path(start.path, start.lam))
    z, margin0 = _check_and_repair(model, z, hazards)
    t_sub = time.perf_counter()
    sub = ConicSubproblem(D)
    setup_time = time.perf_counter() - t_sub
    runner = _ClarabelRunner(solver_options) if solver.upper() == "CLARABEL" else None

    cost, control, info = model.cost(z)
    history = [IterationRecord(0, cost, control, info, "warm_start", min_margin=margin0)]
    iterates = [model.to_path(z)] if keep_iterates else None
    best = z
    rho_fixed = rho
    rho_end = np.full((K, D.J), float(rho)) if rho else initial_rho(model, z)
    rho_start = rho_end.copy()
    status, message = "max_iter", STATUSES["max_iter"]
    solver_total = 0.0
    nit = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_iter, desc="CCP", unit="it")
    for it in range(1, max_iter + 1):
        if time_limit is not None and time.perf_counter() - t_start > time_limit:
            status, message = "time_limit", STATUSES["time_limit"]
            break
        nit = it
        t_it = time.perf_counter()
        v = _pair_vectors(model, z)
        data = sub.build(z, rho_start, rho_end, model.logdet_gradients(z),
                         model.bilinear_gradients(z, end=False), model.bilinear_gradients(z, end=True))
        if _fail_at is not None and it >= _fail_at:
            data.b = data.b.copy()
            data.b[:] = np.nan  # forced failure (tests)
        build_time = time.perf_counter() - t_it
        attempts = [False, True]
        z_new = None
        sstat, sit, stime = "", 0, 0.0
        for safe in attempts:
            if runner is not None:
                try:
                    sstat, sol, st, sit = runner.solve(data, safe=safe)
                except Exception as exc:  # Clarabel raises on NaN data
                    sstat, sol, st, sit = f"error: {exc}", None, 0.0, 0
            else:
                opts = dict(solver_options)
                sstat, sol, st, sit = _cvxpy_solve(data, solver, opts)
            stime += st
            if sol is not None and np.all(np.isfinite(sol)):
                z_raw = sub.extract(sol, z)
                kgap = model.kalman_relative_gap(z_raw)
                z_new = model.tighten(z_raw)
                break
            log.warning("CCP iteration %d: subproblem %s%s", it, sstat, "" if safe else ", retrying with safer settings")
        solver_total += stime
        if z_new is None:
            status, message = "solver_failed", f"{STATUSES['solver_failed']}: solver status {sstat} at iteration {it}"
            history.append(IterationRecord(it, np.nan, np.nan, np.nan, sstat, stime, build_time,
                                           time.perf_counter() - t_it, sit, accepted=False))
            break
        z_new, margin = _check_and_repair(model, z_new, hazards)
        tgt = float(np.min(model.target_margins(z_new)))
        c_new, ctrl_new, info_new = model.cost(z_new)
        rec = IterationRecord(it, c_new, ctrl_new, info_new, sstat, stime, build_time,
                              time.perf_counter() - t_it, sit, accepted=True, min_margin=margin,
                              kalman_gap=kgap)
        if margin < 0 or tgt < 0:
            fixed = _repair(model, z_new, hazards, max(-margin / D.chi2, -tgt, 0.0))
            if fixed is not None:
                z_new, margin, tgt = fixed
                c_new, ctrl_new, info_new = model.cost(z_new)
                rec.cost, rec.control, rec.information = c_new, ctrl_new, info_new
                rec.min_margin = margin
                rec.solver_status = f"{sstat}+repaired"
        if margin < 0 or tgt < 0:
            rec.accepted = False
            history.append(rec)
            status = "infeasible_iterate"
            message = (f"{STATUSES['infeasible_iterate']}: iteration {it} has clearance margin {margin:.3g} "
                       f"and target margin {tgt:.3g}")
            break
        if c_new > cost * (1 + monotone_tol) + 1e-12:
            rec.accepted = False
            history.append(rec)
            status = "non_monotone"
            message = f"{STATUSES['non_monotone']}: cost {cost:.8g} -> {c_new:.8g} at iteration {it}"
            log.warning(message)
            break
        history.append(rec)
        # adapt the split weights to the step just taken (any rho > 0 is valid)
        if rho_fixed is None:
            dv = np.linalg.norm(_pair_vectors(model, z_new) - v, axis=-1)
            dx_end = np.linalg.norm(z_new.x[1:] - z.x[1:], axis=-1)[:, None]
            dx_start = np.linalg.norm(z_new.x[:-1] - z.x[:-1], axis=-1)[:, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                r_end = np.where(dv > 1e-9, dx_end / dv, rho_end)
                r_start = np.where(dv > 1e-9, dx_start / dv, rho_start)
            rho_end = np.clip(np.where(r_end > 0, r_end, rho_end), rho_end / 10, rho_end * 10)
            rho_start = np.clip(np.where(r_start > 0, r_start, rho_start), rho_start / 10, rho_start * 10)
        rel = (cost - c_new) / max(abs(cost), 1e-300)
        z, cost = z_new, c_new
        best = z
        if keep_iterates:
            iterates.append(model.to_path(z))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(cost=f"{cost:.5g}")
        log.info("CCP iteration %d: cost %.8g (control %.4g, info %.4g nats), solver %s %.3fs",
                 it, cost, ctrl_new, info_new, sstat, stime)
        if rel < tol:
            status, message = "converged", f"{STATUSES['converged']} ({rel:.2e} < {tol:g}) after {it} iterations"
            break
    if bar is not None:
        bar.close()
    from ..verify import verify

    path = model.to_path(best, meta={"method": "ccp", "solver": solver, "alpha": D.alpha})
    report = verify(scenario, path)
    c, ctrl, info = model.cost(best)
    if not report.safe:  # never hand out a path that fails the independent check
        bad_report = report
        path, c, ctrl, info = start.path, *model.cost(model.tighten(model.from_path(start.path, start.lam)))
        report = verify(scenario, path)
        status = "infeasible_iterate"
        message = ("the final iterate failed independent verification (" + "; ".join(bad_report.problems[:3])
                   + "); the warm start is returned")
    total = time.perf_counter() - t_start
    return SmoothResult(
        path=path, cost=c, control=ctrl, information=info, success=status == "converged",
        status=status, message=message, nit=nit, history=history, method="ccp", solver=solver,
        alpha=D.alpha, timings={"setup": setup_time, "solver": solver_total, "total": total},
        verification=report.to_dict(), initial_cost=history[0].cost, iterates=iterates)
