"""The active-set CCP step: the model's step as Clarabel's own data
(belief_nlp/model/conic_form.py) with the far (transition, hazard) pairs left
out. Held equal to the CVXPY form of the same model; its answers are taken only
when the exact check accepts them, else the full step follows."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
import belief_nlp.methods.ccp as ccp
from belief_nlp.methods.ccp import SOLVER_DEFAULTS, active_pairs, compiled_step, conic_step_of, initial_rho
from belief_nlp.model.conic_form import ConicStep

from conftest import ccp_problem, paper_multi_path_pair


@pytest.fixture(scope="module")
def case():
    sc, path = paper_multi_path_pair(steps_per_segment=2)          # K = 10
    return (sc, path, *ccp_problem(sc, path))


def _objective(step, zv):
    step.z.value = zv
    return float(step.problem.objective.value)


@pytest.mark.parametrize("settings", [SOLVER_DEFAULTS["CLARABEL"], {}], ids=["library", "defaults"])
def test_all_pairs_kept_equals_the_cvxpy_step(case, settings):
    """Every pair kept: Clarabel on our own data reaches the CVXPY problem's
    optimum (same objective to 1e-7 relative, evaluated by CVXPY), and its
    answer satisfies every CVXPY constraint."""
    sc, path, model, prob = case
    z = prob.start
    rho = initial_rho(model, z)
    rho_e = rho * np.linspace(0.5, 2.0, rho.size).reshape(rho.shape)     # different weights at the two ends
    step = compiled_step(model)[0]
    step.set_point(z, rho, rho_e)
    step.problem.solve(solver="CLARABEL", **settings)
    assert step.problem.status == "optimal"
    ref = step.problem.value
    status, zv, _, _ = conic_step_of(model).solve(z, rho, rho_e, np.ones(model.data.K * model.data.J, bool),
                                                  settings)
    assert status == "optimal"
    assert _objective(step, zv) == pytest.approx(ref, rel=1e-7, abs=1e-9)
    for c in step.problem.constraints:
        assert np.max(np.atleast_1d(c.violation())) < 1e-6, c


def test_far_pairs_left_out_keep_the_step_monotone_and_the_kept_pairs_safe(case):
    """Only the near pairs: an answer that does not raise the cost, every kept
    pair exactly safe (dense independent minimum over the segment), the
    left-out pairs' certificates at the point; adding the pairs the answer came
    near and solving again (the library's constraint generation) ends exactly
    safe."""
    sc, path, model, prob = case
    z = prob.start
    rho = initial_rho(model, z)
    keep = active_pairs(model, z, prob.hazards_scaled)
    assert 0 < keep.sum() < keep.size
    step = compiled_step(model)[0]
    for _ in range(ccp.ACTIVE_ROUNDS):
        status, zv, _, _ = conic_step_of(model).solve(z, rho, rho, keep, SOLVER_DEFAULTS["CLARABEL"])
        assert status == "optimal"
        new = model.tighten(step.layout.extract(zv, z))
        far = ~keep.reshape(model.data.K, model.data.J)
        np.testing.assert_array_equal(new.lam[far], z.lam[far])
        assert model.cost(new)[0] <= prob.cost0 * (1 + 1e-9)
        d2 = _dense_dist2(model, new, sc)
        assert np.all(d2.ravel()[keep] >= model.data.chi2 * (1 - 1e-6))
        near = active_pairs(model, new, prob.hazards_scaled)
        if not np.any(near & ~keep):
            break
        keep = keep | near
    chk = prob.check(new)
    assert chk.safe
    assert bn.verify(sc, model.to_path(chk.point)).safe


def _polygon_edges(A, b):
    """Each face of {y : A y <= b} (2-D, possibly unbounded) as y0 + t d,
    t in [lo, hi] (infinite ends allowed); empty faces left out."""
    edges = []
    for f in range(len(b)):
        a = A[f]
        y0 = a * b[f] / (a @ a)
        d = np.array([-a[1], a[0]])
        lo, hi = -np.inf, np.inf
        for g in range(len(b)):
            if g == f:
                continue
            c, r = A[g] @ d, b[g] - A[g] @ y0          # c t <= r
            if abs(c) < 1e-14:
                if r < 0:
                    lo, hi = 1.0, 0.0
                continue
            lo, hi = (lo, min(hi, r / c)) if c > 0 else (max(lo, r / c), hi)
        if lo <= hi:
            edges.append((y0, d, lo, hi))
    return edges


def _dense_dist2(model, point, sc, n=201):
    """(K, J) min over a dense grid of s in [0, 1] of the squared Mahalanobis
    distance from x(s) to hazard j under P(s) (the transition of
    ``model.segments``, scaled units): whitened point-to-face distances of the
    polygon, independent of the library's minimiser (an upper bound of the
    exact minimum, close on a fine grid)."""
    xp, C, xn, V = model.segments(point)
    s = np.linspace(0.0, 1.0, n)
    out = np.zeros((len(xp), len(sc.hazards)))
    for j, h in enumerate(sc.hazards):
        A, b = np.asarray(h.A, float), np.asarray(h.b, float) / model.data.sigma
        edges = _polygon_edges(A, b)
        for k in range(len(xp)):
            m = xp[k] + s[:, None] * (xn[k] - xp[k])
            L = np.linalg.cholesky(C[k] + s[:, None, None] * V[k])
            inside = np.all(m @ A.T <= b, axis=1)
            best = np.full(n, np.inf)
            for y0, d, lo, hi in edges:
                w = np.linalg.solve(L, (m - y0)[..., None])[..., 0]
                e = np.linalg.solve(L, np.broadcast_to(d, m.shape)[..., None])[..., 0]
                t = np.clip(np.sum(w * e, axis=1) / np.sum(e * e, axis=1), lo, hi)
                best = np.minimum(best, np.sum((w - t[:, None] * e) ** 2, axis=1))
            out[k, j] = 0.0 if inside.any() else best.min()
    return out


def test_active_set_run_matches_the_full_run(case):
    """The default run (active set) and the full-step run: both converged and
    verified, the same cost to the stopping tolerance, and the active-set steps
    were the ones taken."""
    sc, path, model, prob = case
    fast = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5)
    full = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, active_set=False)
    assert fast.status == full.status == "converged"
    assert bn.verify(sc, fast.path).safe and bn.verify(sc, full.path).safe
    assert fast.cost == pytest.approx(full.cost, rel=1e-4)
    taken = [str(s["solver"]) for s in fast.stats["steps"]]
    assert sum("active set" in t for t in taken) >= len(taken) - 1
    assert not any("active set" in str(s["solver"]) for s in full.stats["steps"])
    assert len(fast.stats["active_pairs"]) >= fast.nit
    assert max(fast.stats["active_pairs"]) < model.data.K * model.data.J
    # the CVXPY step is compiled only when a step needed it
    cvxpy_entries = [a for s in fast.stats["steps"] for a in s["attempts"] if a["settings"] not in ("active set",
                                                                                                     "proximal")]
    assert (fast.stats["compile"] == "not needed") == (not cvxpy_entries)
    assert full.stats["compile"] in ("compiled", "memory")


def test_a_refused_active_set_answer_sends_the_step_to_the_full_problem(case, monkeypatch):
    """With no pair kept and no constraint generation the step ignores every
    hazard; the exact check refuses those answers and the full step (on the
    same Clarabel data, every pair kept) answers instead, without compiling
    the CVXPY step: the run stays monotone, converges and is verified."""
    sc, path, model, prob = case
    monkeypatch.setattr(ccp, "ACTIVE_FACTOR", 0.0)
    monkeypatch.setattr(ccp, "ACTIVE_ROUNDS", 1)
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, keep_iterates=True,
                  accelerate=False)
    assert r.status == "converged", r.message
    assert bn.verify(sc, r.path).safe
    steps = r.stats["steps"]
    assert all(s["attempts"][0]["settings"] == "active set" for s in steps)
    assert any(str(s["solver"]) == "CLARABEL (full step)" for s in steps)
    # CVXPY is compiled only for a step whose full-step answer was not taken
    # (Clarabel's "almost solved" on a marginal step is not ours to assert away)
    fell_through = [s for s in steps if not str(s["solver"]).startswith("CLARABEL (active set")
                    and str(s["solver"]) != "CLARABEL (full step)"]
    assert (r.stats["compile"] == "not needed") == (not fell_through)
    costs = [h.cost for h in r.history if h.accepted]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:]))


def test_an_inaccurate_active_set_answer_waits_for_the_full_step_on_the_same_data(case, monkeypatch):
    """Clarabel's 'almost solved' on the active-set step (seen on 3 of 20
    warmed auto calls) sent the step to CVXPY, whose import and compile cost
    0.7-1.4 s in that call. The full step on the active-set step's own data
    answers first now; its answers agree with the CVXPY full steps' run
    (an independent form of the same problem)."""
    sc, path, model, prob = case
    real = ConicStep.solve

    def almost(self, point, rho_s, rho_e, keep, *args, **kwargs):
        status, zv, t, n = real(self, point, rho_s, rho_e, keep, *args, **kwargs)
        return ("optimal_inaccurate" if not np.all(keep) else status), zv, t, n

    monkeypatch.setattr(ConicStep, "solve", almost)
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, accelerate=False)
    monkeypatch.undo()
    full = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, accelerate=False, active_set=False)
    assert r.status == full.status == "converged", r.message
    assert bn.verify(sc, r.path).safe
    # every step is answered on the active-set step's own data (the full step),
    # unless that answer too was inaccurate: only then is CVXPY compiled
    fell_through = [s for s in r.stats["steps"] if str(s["solver"]) != "CLARABEL (full step)"]
    assert all(any(a["settings"] == "full step" and a["status"] != "optimal" for a in s["attempts"])
               for s in fell_through)
    assert (r.stats["compile"] == "not needed") == (not fell_through)
    assert r.cost == pytest.approx(full.cost, rel=1e-6) and r.nit == full.nit


def test_active_set_is_off_with_user_constraints_and_must_be_a_bool(case):
    sc, path, model, prob = case
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=2, constraints=lambda step: [])
    assert not any("active set" in str(s["solver"]) for s in r.stats["steps"])
    with pytest.raises(bn.ValidationError, match="active_set"):
        bn.smooth(sc, path, method="ccp", active_set=1)


@pytest.mark.parametrize("fault", ["zeros", "huge", "short", "nan"])
def test_a_nonsense_active_set_answer_goes_to_the_full_step(case, monkeypatch, fault):
    """The active-set solve reports success with zeros, 1e300, a wrong-length or
    a NaN vector: the answer is unusable (recorded so), the full step answers,
    the run converges verified."""
    sc, path, model, prob = case
    real = ConicStep.solve

    def lying(self, *args, **kwargs):
        status, zv, t, n = real(self, *args, **kwargs)
        bad = {"zeros": np.zeros_like(zv), "huge": np.full_like(zv, 1e300), "short": zv[:-3],
               "nan": np.where(np.arange(zv.size) % 7 == 0, np.nan, zv)}[fault]
        return "optimal", bad, t, n

    monkeypatch.setattr(ConicStep, "solve", lying)
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5)
    assert r.status == "converged", r.message
    assert bn.verify(sc, r.path).safe and r.cost < r.initial_cost
    first = [s["attempts"][0] for s in r.stats["steps"]]
    assert all(a["settings"] == "active set" for a in first)
    assert all("unusable" in a["status"] or "degenerate" in a["status"] or "not taken" in a["status"]
               for a in first), first
    assert not any("active set" in str(s["solver"]) for s in r.stats["steps"])


class PanicException(BaseException):
    """What pyo3 raises when a Rust solver panics (its name is what is matched):
    a BaseException, invisible to ``except Exception``."""


def test_a_solver_panic_is_a_failed_solve(case, monkeypatch):
    """Clarabel panicked inside the active-set step once (an eigenvalue failure
    in its PSD step length, seen in CI): the step must count as failed and the
    cascade go on -- every active-set solve panics here, the full CVXPY steps
    answer, the run converges verified."""
    import sys

    import clarabel

    real = clarabel.DefaultSolver

    class Panicking:
        def solve(self):
            raise PanicException("Eigval error: Eigen(1)")

    def solver(*args, **kwargs):          # the active-set step's solves panic, CVXPY's do not
        if sys._getframe(1).f_globals.get("__name__") == "belief_nlp.model.conic_form":
            return Panicking()
        return real(*args, **kwargs)

    monkeypatch.setattr(clarabel, "DefaultSolver", solver)
    sc, path, model, prob = case
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5)
    monkeypatch.undo()
    assert r.status == "converged", r.message
    assert bn.verify(sc, r.path).safe and r.cost < r.initial_cost
    first = [s["attempts"][0] for s in r.stats["steps"]]
    assert all(a["settings"] == "active set" and "panicked" in a["status"] for a in first), first
    assert not any("active set" in str(s["solver"]) for s in r.stats["steps"])


def test_other_base_exceptions_are_not_swallowed(case, monkeypatch):
    """Only a solver's panic is a failed solve: a KeyboardInterrupt in a solve
    still stops the run."""
    import clarabel

    class Interrupted:
        def __init__(self, *args, **kwargs):
            pass

        def solve(self):
            raise KeyboardInterrupt

    monkeypatch.setattr(clarabel, "DefaultSolver", Interrupted)
    sc, path, model, prob = case
    with pytest.raises(KeyboardInterrupt):
        bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=3)


def test_a_run_on_the_active_set_step_never_imports_cvxpy(tmp_path):
    """The default CCP run is answered by the active-set step (Clarabel's own
    API): checking the default solver and running the steps import no CVXPY
    (its import was ~0.35 s of a process's first ccp call). A solver CVXPY
    does not have is still refused by name."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import belief_nlp as bn\n"
        "sc = bn.load_scenario('paper-multi')\n"
        "path = bn.plan(sc, n_nodes=200, seed=0, noise='per_step').path\n"
        "res = bn.smooth(sc, path, method='ccp', K=8, alpha=1.0, max_iter=3)\n"
        "print(res.safe, all('active set' in s['solver'] for s in res.stats['steps']), 'cvxpy' in sys.modules)\n"
        "try:\n"
        "    bn.smooth(sc, path, method='ccp', K=8, solver='NOSUCH')\n"
        "except bn.errors.ValidationError as exc:\n"
        "    print(exc.field)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    first, second = out.stdout.strip().splitlines()[-2:]
    assert first == "True True False"
    assert second == "solver"


def test_insufficient_progress_is_an_inaccurate_answer_in_both_entries(case):
    """Clarabel made to stop at InsufficientProgress (a large static
    regularisation): the own-data step and the CVXPY entry of the cascade
    both call the point an inaccurate answer (one meaning of the status;
    the exact check and the monotone test decide on it), and the point is
    near the step's optimum by the CVXPY objective."""
    from belief_nlp.methods.ccp_cascade import _solve

    sc, path, model, prob = case
    z = prob.start
    rho = initial_rho(model, z)
    step = compiled_step(model)[0]
    step.set_point(z, rho, rho)
    step.problem.solve(solver="CLARABEL")
    ref = step.problem.value
    stall = {"static_regularization_constant": 1e-2}
    status, zv, _, _ = conic_step_of(model).solve(z, rho, rho, np.ones(model.data.K * model.data.J, bool), stall)
    assert status == "optimal_inaccurate"
    assert _objective(step, zv) == pytest.approx(ref, rel=1e-2)
    status, zv, _, _ = _solve(step, "CLARABEL", stall)
    assert status == "optimal_inaccurate"
    assert _objective(step, zv) == pytest.approx(ref, rel=1e-2)
