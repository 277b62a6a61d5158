"""smooth() rejects bad arguments up front with our error naming the argument,
and degrades honestly when its solver answers nonsense (issue: hardening)."""

from __future__ import annotations

import time

import numpy as np
import pytest

import belief_nlp as bn
import belief_nlp.methods.ccp_cascade as ccp_cascade
from belief_nlp.errors import ValidationError

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=1)        # K = 5


@pytest.mark.parametrize("kwargs, field", [
    ({"alpha": float("nan")}, "alpha"), ({"alpha": float("inf")}, "alpha"), ({"alpha": -1.0}, "alpha"),
    ({"alpha": 4.0463340028e10}, "alpha"),      # above the scenario's bound: CCP ground for 62 s there
    ({"time_limit": float("nan")}, "time_limit"), ({"time_limit": 0}, "time_limit"),
    ({"tol": float("nan")}, "tol"), ({"tol": 2.0}, "tol"),
    ({"max_iter": 0}, "max_iter"), ({"max_iter": 2.5}, "max_iter"), ({"max_iter": True}, "max_iter"),
    ({"K": 10**9}, "K"), ({"K": "20"}, "K"),
    ({"solver": "FOO"}, "solver"), ({"solver": 3}, "solver"),
    ({"solver_options": "x"}, "solver_options"),
    ({"solver_options": {"no_such_setting": 1}, "method": "ccp"}, "solver_options"),
    ({"monotone_tol": float("nan"), "method": "ccp"}, "monotone_tol"), ({"rho": -1.0, "method": "ccp"}, "rho"),
    ({"rho": 1.97e19, "method": "ccp"}, "rho"),  # the fuzz test's: no Clarabel answer, SCS 28 s for 2 iterations
    # ints no float can hold (the fuzz test's 10**400 overflowed inside the run)
    ({"alpha": 10**400}, "alpha"), ({"monotone_tol": 10**400, "method": "ccp"}, "monotone_tol"),
    ({"floor": 10**400, "method": "ipopt"}, "floor"),
    ({"max_ter": 3}, "max_ter"), ({"callback": 3}, "callback"),
    ({"method": "newton"}, "method"), ({"method": 3}, "method"),
    ({"formulation": "nope", "method": "ipopt"}, "formulation"),
])
def test_bad_arguments_are_named_fast(small, kwargs, field):
    sc, path = small
    t0 = time.perf_counter()
    with pytest.raises(ValidationError) as exc:
        bn.smooth(sc, path, **kwargs)
    assert exc.value.field == field
    assert time.perf_counter() - t0 < 5.0          # rejected before any solver work (generous bound)


def test_bad_scenario_and_path_arguments(small):
    sc, path = small
    for scenario, field in ((None, "scenario"), (3, "scenario")):
        with pytest.raises(ValidationError) as exc:
            bn.smooth(scenario, path)
        assert exc.value.field == field
    with pytest.raises(ValidationError) as exc:
        bn.smooth(sc, "not a path")
    assert exc.value.field == "path"


def test_numpy_integers_are_integers(small):
    sc, path = small
    res = bn.smooth(sc, path, max_iter=np.int64(2), K=np.int64(5))
    assert res.nit <= 2 and res.safe


@pytest.mark.parametrize("fault", ["zeros", "huge", "short", "nan"])
def test_a_nonsense_solver_answer_is_a_failed_subproblem(small, monkeypatch, fault):
    """A solver that reports success with zeros, 1e300, a wrong-length or a
    NaN vector: every such answer is refused (never a step of the run), the
    run ends unsuccessful with a typed status, the answer is verified and
    never above the warm start. (Whether the run ends by the cascade's
    failure or at max_iter depends on when the honest proximal entry, which
    does not go through the lying solve, fails: not asserted.)"""
    sc, path = small
    real = ccp_cascade._solve
    calls, told = [], []

    def lying(step, *args, **kwargs):
        status, zv, t, n = real(step, *args, **kwargs)
        calls.append(1)
        if len(calls) < 2 or zv is None:
            return status, zv, t, n
        bad = {"zeros": np.zeros_like(zv), "huge": np.full_like(zv, 1e300), "short": zv[:-3],
               "nan": np.where(np.arange(zv.size) % 7 == 0, np.nan, zv)}[fault]
        told.append(1)
        return "optimal", bad, t, n

    monkeypatch.setattr(ccp_cascade, "_solve", lambda *a, **k: ccp_cascade._checked(*lying(*a, **k), a[0]))
    res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=6, active_set=False)     # CVXPY steps only
    assert res.status in ("solver_failed", "infeasible_iterate", "max_iter") and not res.success
    attempts = [a for step in res.stats["steps"] for a in step["attempts"]]
    lies = [a for a in attempts if a["status"].endswith(("(degenerate answer)", "(unusable answer)"))]
    assert told and len(lies) == len(told)                                   # every lie was refused
    for step in res.stats["steps"]:                                          # and none was taken
        taken = [a for a in step["attempts"] if f"{a['solver']} ({a['settings']})" == step["solver"]]
        assert step["solver"] is None or taken[-1]["status"] in ("optimal", "optimal_inaccurate")
    assert res.safe and res.cost <= res.initial_cost
    assert bn.verify(sc, res.path, certificates=res.certificates).proof == "certificates+sampling"


def test_a_horizon_infeasible_by_length_is_allotted_by_feasibility():
    """IG-RRT* seed 9 (N = 300, alpha = 0.1, per-step noise) gives a 3-edge plan
    whose steps allotted by length make a sub-step next to an obstacle
    infeasible; allotting them where they stay clear gives K = 20."""
    sc = bn.load_scenario("paper-multi")
    planned = bn.plan(sc, n_nodes=300, seed=9, alpha=0.1, noise="per_step", max_radius=1.5)
    ws = bn.warm_start(sc, planned.path, K=20)
    assert ws.K == 20 and ws.allocation == "feasibility" and bn.verify(sc, ws.path).safe
    for v in planned.path.x:                                   # every vertex of the plan kept
        assert np.min(np.linalg.norm(ws.path.x - v, axis=1)) < 1e-12


def test_an_infeasible_horizon_falls_back_to_one_step_per_edge_and_says_so(monkeypatch):
    """When no allocation at K works, smooth falls back to one step per edge
    and says so, or raises when told not to (simulated: K-step starts refused)."""
    import belief_nlp.smoother.driver as driver

    sc, path = paper_multi_path_pair(steps_per_segment=1)        # 5 edges
    real = driver.warm_start

    def refuse_k(scenario, p, K=None, sensing="minimal", **kw):
        if K is not None and K != p.K:
            raise bn.InfeasibleStartError("no feasible allocation (simulated)", transition=1, obstacle="x")
        return real(scenario, p, K=K, sensing=sensing, **kw)

    monkeypatch.setattr(driver, "warm_start", refuse_k)
    res = bn.smooth(sc, path, K=20, max_iter=3)
    ws = res.stats["warm_start"]
    assert ws["fallback"] and ws["requested_K"] == 20 and ws["K"] == path.K == res.path.K
    assert "one step per path edge" in res.message and res.safe
    with pytest.raises(bn.InfeasibleStartError):
        bn.smooth(sc, path, K=20, max_iter=3, k_fallback=False)


def test_method_names_are_case_insensitive(small):
    """`method="CCP"` is the registered "ccp" (solver names are case-insensitive too)."""
    from belief_nlp.smoother.registry import get_method

    assert get_method("CCP") is get_method("ccp") and get_method("Auto").name == "auto"
    with pytest.raises(bn.ValidationError, match="method"):
        get_method("no-such-method")


def test_a_solver_that_is_not_installed_is_named_so(small):
    sc, path = small
    with pytest.raises(bn.ValidationError, match="not installed"):
        bn.smooth(sc, path, method="ccp", solver="NO_SUCH_SOLVER_XYZ", max_iter=1)


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_smooth_reads_the_path_files_the_cli_reads(small, tmp_path, suffix):
    """A plan or path file given as str or pathlib.Path smooths like the
    object itself (the same warm start, the same answer); a bad file names `path`."""
    from pathlib import Path

    sc, path = small
    f = path.save(tmp_path / f"p{suffix}")
    ref = bn.smooth(sc, path, method="ccp", max_iter=2)
    for given in (str(f), Path(f)):
        res = bn.smooth(sc, given, method="ccp", max_iter=2)
        assert res.cost == pytest.approx(ref.cost, rel=1e-9) and res.safe
    bad = tmp_path / "bad.json"
    bad.write_text("[" * 100 + "]" * 100)
    with pytest.raises(bn.ValidationError, match="path"):
        bn.smooth(sc, str(bad), max_iter=1)
    with pytest.raises(bn.ValidationError, match="no such file"):
        bn.smooth(sc, str(tmp_path / "missing.npz"), max_iter=1)


@pytest.mark.parametrize("method", ["ccp", "ipopt"])
def test_a_callback_may_stop_the_run_with_stop_iteration(small, method):
    """scipy.optimize's habit: raising StopIteration in the callback stops the
    run after that iteration, status 'stopped', the answer verified."""
    sc, path = small
    seen = []

    def cb(rec):
        seen.append(rec.iteration)
        if len(seen) >= 2:
            raise StopIteration

    res = bn.smooth(sc, path, method=method, callback=cb, max_iter=40)
    assert res.status == "stopped" and len(seen) == 2 and res.safe and res.cost <= res.initial_cost


def test_available_solvers_lists_what_each_method_accepts():
    """qpsolvers' habit: the usable solvers of a method, its default first;
    every one passes the method's own solver check, and smooth takes it."""
    for name in bn.available_methods():
        m = bn.get_method(name)
        solvers = bn.available_solvers(name)
        assert solvers, name
        assert solvers[0].upper() == m.default_solver.upper()
        if m.check_solver is not None:
            assert all(m.check_solver(s) is None for s in solvers), name
    assert "CLARABEL" in bn.available_solvers("ccp")
    assert bn.available_solvers() == bn.available_solvers(bn.DEFAULT_METHOD)
    with pytest.raises(bn.ValidationError, match="method"):
        bn.available_solvers("no-such-method")


def test_method_options_as_a_dict_like_scipy():
    """options={...} means the same as the keywords; a clash or a non-dict is named."""
    from belief_nlp.smoother.driver import _merge_options

    assert _merge_options({"options": {"rho": 2.0}, "monotone_tol": 1e-6}) == {"rho": 2.0, "monotone_tol": 1e-6}
    assert _merge_options({"rho": 2.0}) == {"rho": 2.0}
    with pytest.raises(bn.ValidationError, match="options"):
        _merge_options({"options": {"rho": 2.0}, "rho": 3.0})
    with pytest.raises(bn.ValidationError, match="options"):
        _merge_options({"options": [("rho", 2.0)]})
    sc = bn.load_scenario("paper-multi")
    path = bn.plan(sc, n_nodes=150, seed=0, noise="per_step").path
    with pytest.raises(bn.ValidationError, match="no_such_option"):
        bn.smooth(sc, path, method="ccp", options={"no_such_option": 1})
    a = bn.smooth(sc, path, method="ccp", max_iter=2, options={"monotone_tol": 1e-6})
    b = bn.smooth(sc, path, method="ccp", max_iter=2, monotone_tol=1e-6)
    assert a.cost == b.cost


def test_unverified_warm_start_is_the_verified_one_and_smooth_verifies_its_answer():
    """warm_start(verify_start=False) (what smooth builds) is the same start
    without the report; smooth still verifies the path it returns, here the
    warm start itself (max_iter=1 keeps no better iterate)."""
    from conftest import paper_multi_path_pair

    sc, path = paper_multi_path_pair(steps_per_segment=2)
    full = bn.warm_start(sc, path)
    lazy = bn.warm_start(sc, path, verify_start=False)
    assert full.report.safe and lazy.report is None
    np.testing.assert_array_equal(lazy.path.x, full.path.x)
    np.testing.assert_array_equal(lazy.path.P, full.path.P)
    np.testing.assert_array_equal(lazy.lam, full.lam)
    res = bn.smooth(sc, path, method="ccp", max_iter=1, time_limit=1e-9)
    assert res.cost == pytest.approx(res.initial_cost) and res.safe
    assert res.verification["safe"] and bn.verify(sc, res.path).safe


@pytest.mark.parametrize("K", [None, 20])
def test_warm_start_senses_only_where_the_next_transition_needs_it(K):
    """The minimal-sensing warm start (transitions checked in one batch, step
    by step only from the first that is not clear) halves a posterior only
    when the next transition needs it: each P_k is its prior P_{k-1} + W halved
    h_k times, the h_k add up to ``added_sensing``, every transition clears
    the start level, and with one halving fewer at a step that sensed, the
    next transition would not (exact minimisation over the transition)."""
    from belief_nlp.geometry import PolytopeSet, transition_minimiser
    from belief_nlp.smoother.warmstart import _START_MARGIN

    sc = bn.load_scenario("paper-multi")
    ws = bn.warm_start(sc, bn.plan(sc, n_nodes=300, seed=2).path, K=K)
    x, P, W = ws.path.x, ws.path.P, np.asarray(sc.W)
    thr = sc.chi2 * (1 + _START_MARGIN)
    hz = PolytopeSet.build(sc.hazards)
    h = []
    for k in range(1, ws.K + 1):
        prior = P[k - 1] + W
        n = int(round(np.log2(np.trace(prior) / np.trace(P[k]))))
        np.testing.assert_allclose(P[k] * 2.0**n, prior, rtol=1e-12)
        h.append(n)
    assert ws.added_sensing == sum(h) > 0
    assert np.all(transition_minimiser(x[:-1], P[:-1], x[1:], W, hz).dist2 >= thr)
    sensed = [k for k in range(1, ws.K) if h[k - 1] > 0]
    assert sensed
    for k in sensed:
        fewer = transition_minimiser(x[k], 2 * P[k], x[k + 1], W, hz, threshold=thr)
        assert np.any(fewer.dist2 < thr), k


def test_check_of_a_point_seen_before_is_the_same_proof():
    """SmoothingProblem.check returns its earlier result for a point with the
    same content (a copy too), recomputes for changed content, and the
    result equals a fresh computation (_check)."""
    from belief_nlp.model import BeliefModel
    from belief_nlp.smoother.context import SmoothingProblem

    sc, path = paper_multi_path_pair(steps_per_segment=2)
    ws = bn.warm_start(sc, path)
    model = BeliefModel(sc, ws.K, 0.1)
    prob = SmoothingProblem(sc, ws, model, max_iter=10, tol=1e-4, time_limit=None, t0=time.perf_counter(),
                            solver=None, solver_options={}, progress=False, keep_iterates=False, callback=None,
                            method="test")
    z = prob.start.copy()
    first = prob.check(z)
    assert prob.check(z.copy()) is first
    fresh = prob._check(z.copy())
    assert (fresh.margin, fresh.target, fresh.upper) == (first.margin, first.target, first.upper)
    # shrink every certificate: a different point, a different (weaker) proof
    z2 = z.copy()
    z2.lam = 0.5 * z2.lam
    other = prob.check(z2)
    assert other is not first and other.margin != first.margin
    # a result whose point is changed afterwards is not handed out again
    first.point.x[1, 0] += 1e-3
    again = prob.check(z)
    assert again is not first and again.margin == prob._check(z).margin


def test_a_checks_exact_minimum_is_of_the_point_it_checked():
    """Check.upper (the exact minimisation, not part of the proof) is
    computed when first read, from the point as it was checked: changing
    the point afterwards does not change it; and it bounds the proof from
    above (margin <= upper)."""
    from belief_nlp.model import BeliefModel
    from belief_nlp.smoother.context import SmoothingProblem

    sc, path = paper_multi_path_pair(steps_per_segment=2)
    ws = bn.warm_start(sc, path)
    prob = SmoothingProblem(sc, ws, BeliefModel(sc, ws.K, 0.1), max_iter=10, tol=1e-4, time_limit=None,
                            t0=time.perf_counter(), solver=None, solver_options={}, progress=False,
                            keep_iterates=False, callback=None, method="test")
    z = prob.start.copy()
    chk = prob._check(z)
    assert "upper" not in vars(chk)                 # not computed yet
    want = prob._check(z.copy()).upper
    z.x[1:-1] += 0.05                               # the checked point moves (chk.point may be z itself)
    chk.point.x[1:-1] += 0.05
    assert chk.upper == want and chk.margin <= chk.upper
