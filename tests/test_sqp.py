"""The SQP baseline (belief_nlp.methods.sqp: Uno's filter-SQP through unopy or CasADi's plug-in)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods.sqp import map_status
from belief_nlp.methods.sqp_unopy import HAVE_UNOPY, UnopySolver, return_status

from conftest import paper_multi_path_pair


def test_sqp_reaches_ipopts_optimum_from_the_same_start(hand_start, ipopt_from):
    """Two NLP solvers on one NLP: the SQP answer is converged, verified and
    within 0.1 % of IPOPT's (both polish on the exact Cholesky NLP)."""
    sc, ws = hand_start          # tests/conftest.py, with ipopt_from
    sqp = bn.smooth(sc, ws, method="sqp", alpha=1.0)
    ipo = ipopt_from(hand_start, 1.0)
    assert sqp.method == "sqp" and sqp.solver == "Uno" and sqp.status == "converged" and sqp.success
    assert sqp.safe and bn.verify(sc, sqp.path).safe
    assert sqp.cost == pytest.approx(ipo.cost, rel=1e-3)
    assert sqp.cost < sqp.initial_cost
    att = sqp.stats["attempts"]
    assert att[0]["formulation"] == "logchol" and map_status(att[0]["return_status"]) == "converged"
    assert sqp.stats["iter_count"] == sum(a["iter_count"] for a in att) > 0
    assert sqp.stats["restoration"] is None          # Uno's plug-in does not report it: no made-up zero


def test_status_mapping():
    assert map_status("Converged with feasible KKT point") == "converged"
    assert map_status("Maximum_Iterations_Exceeded") == "max_iter"
    assert map_status("Maximum_WallTime_Exceeded") == "time_limit"
    assert map_status("Terminated with infeasible point") == "solver_failed"


def test_bad_solver_and_options_are_our_errors(hand_start):
    sc, ws = hand_start
    with pytest.raises(ValidationError) as e:
        bn.smooth(sc, ws, method="sqp", solver="IPOPT")
    assert e.value.field == "solver"
    for bad in ({"preset": "byrd"}, {"max_iterations": [10]}):     # CasADi passes Uno's options unchecked
        with pytest.raises(ValidationError) as e:
            bn.smooth(sc, ws, method="sqp", solver_options=bad)
        assert e.value.field == "solver_options"


# --- the unopy interface (Uno's own bindings, the sparse Hessian) -------------

needs_unopy = pytest.mark.skipif(not HAVE_UNOPY, reason="unopy is not installed (pip install -e '.[sqp]')")


@pytest.fixture(scope="module")
def tiny_start():
    sc, path = paper_multi_path_pair(steps_per_segment=1)          # K = 5
    return sc, bn.warm_start(sc, path)


@needs_unopy
def test_unopy_solver_converges_quadratically_on_a_known_problem():
    """min (x-1)^2 + (y-2)^2 s.t. x^2 + y^2 <= 1: the answer (1, 2)/sqrt(5) with
    multiplier sqrt(5) - 1. With the generated Hessian's sign right Uno's SQP
    takes a handful of iterations (with the constraint's curvature flipped it
    took 37): the Hessian, Jacobian and multipliers reach Uno as they should."""
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 1)
    solver = UnopySolver({"x": x, "p": p, "f": (x[0] - p[0]) ** 2 + (x[1] - 2) ** 2, "g": ca.sumsqr(x)},
                         {"preset": "filtersqp", "logger": "SILENT"})
    sol = solver(x0=[3.0, -2.0], p=[1.0], lbx=-10.0, ubx=10.0, lbg=-np.inf, ubg=1.0)
    st = solver.stats()
    assert map_status(st["return_status"]) == "converged" and st["success"]
    assert np.allclose(sol["x"], np.array([1.0, 2.0]) / np.sqrt(5), atol=1e-7)
    assert sol["f"] == pytest.approx((np.sqrt(5) - 1) ** 2, rel=1e-8)
    assert st["iter_count"] <= 10


@needs_unopy
def test_both_interfaces_and_ipopt_reach_one_optimum(tiny_start):
    """unopy and CasADi's plug-in run the same SQP on the same NLP: converged,
    verified, and the same cost as IPOPT to 0.1 %; unopy's raw statistics
    and one history record per Uno iteration."""
    sc, ws = tiny_start
    ipo = bn.smooth(sc, ws, method="ipopt", alpha=1.0)
    runs = {i: bn.smooth(sc, ws, method="sqp", alpha=1.0, interface=i) for i in ("unopy", "casadi")}
    for iface, r in runs.items():
        assert r.status == "converged" and r.safe and bn.verify(sc, r.path).safe, iface
        assert r.cost == pytest.approx(ipo.cost, rel=1e-3), iface
    u = runs["unopy"]
    assert u.stats["interface"].startswith("unopy") and "CasADi" in runs["casadi"].stats["interface"]
    first = u.stats["attempts"][0]
    assert first["optimization_status"] == "SUCCESS" and first["solution_status"] == "FEASIBLE_KKT_POINT"
    assert first["evaluations"]["hess_l"] >= first["iter_count"] > 0    # the explicit Hessian, once an iteration
    # the warm start's record, then one per Uno iteration (the polish continues the count)
    assert [h.iteration for h in u.history] == list(range(u.stats["iter_count"] + 1)) and u.nit == u.stats["iter_count"]
    assert u.history[-1].cost == pytest.approx(u.cost, rel=1e-6)


@needs_unopy
def test_unopy_budget_stops_are_honest(tiny_start):
    """An iteration or time budget ends the run with that status and an exactly
    safe answer no costlier than the warm start."""
    sc, ws = tiny_start
    r = bn.smooth(sc, ws, method="sqp", alpha=1.0, max_iter=3)
    assert r.status == "max_iter" and r.stats["iter_count"] <= 3
    assert r.safe and bn.verify(sc, r.path).safe and r.cost <= r.initial_cost * (1 + 1e-12)
    assert [h.iteration for h in r.history] == list(range(r.stats["iter_count"] + 1))
    # a limit below one iteration's time on any host (0.05 s let a fast host converge)
    t = bn.smooth(sc, ws, method="sqp", alpha=1.0, time_limit=1e-4)
    assert t.status == "time_limit" and t.safe and bn.verify(sc, t.path).safe


@needs_unopy
def test_unopy_bad_options_are_our_errors(tiny_start):
    """unopy checks option names and types (CasADi's plug-in ignores unknown
    names): each refusal is our ValidationError, as is a bad interface."""
    sc, ws = tiny_start
    for bad in ({"no_such_option": 1}, {"primal_tolerance": "tight"}, {"preset": "byrd"}):
        with pytest.raises(ValidationError) as e:
            bn.smooth(sc, ws, method="sqp", solver_options=bad, interface="unopy")
        assert e.value.field == "solver_options"
    with pytest.raises(ValidationError) as e:
        bn.smooth(sc, ws, method="sqp", interface="knitro")
    assert e.value.field == "interface"


def test_unopy_status_texts_map_to_ours():
    assert map_status(return_status("SUCCESS", "FEASIBLE_KKT_POINT")) == "converged"
    assert map_status(return_status("ITERATION_LIMIT", "NOT_OPTIMAL")) == "max_iter"
    assert map_status(return_status("TIME_LIMIT", "NOT_OPTIMAL")) == "time_limit"
    for opt, sol in (("SUCCESS", "INFEASIBLE_STATIONARY_POINT"), ("SUCCESS", "FEASIBLE_SMALL_STEP"),
                     ("ALGORITHMIC_ERROR", "NOT_OPTIMAL"), ("EVALUATION_ERROR", "NOT_OPTIMAL")):
        assert map_status(return_status(opt, sol)) == "solver_failed", (opt, sol)


def test_without_unopy_auto_falls_back_to_casadis_plugin(tiny_start, monkeypatch):
    """interface="auto" runs CasADi's plug-in when unopy is not installed."""
    from belief_nlp.methods import sqp

    monkeypatch.setattr(sqp, "HAVE_UNOPY", False)
    sc, ws = tiny_start
    r = bn.smooth(sc, ws, method="sqp", alpha=1.0, max_iter=4)
    assert "CasADi" in r.stats["interface"] and r.solver == "Uno"
    assert r.status == "max_iter" and r.safe and "optimization_status" not in r.stats["attempts"][0]


def test_casadis_plugin_history_reads_the_iterates_own_rows(tiny_start):
    """CasADi's Uno plug-in hands the iteration callback no f and g (NULL):
    the recorder evaluates them at the iterate instead of reading zeros, so
    the history's margins and Kalman gaps are the iterates' own (before: 0.0
    in every record, and no iterate counted as a feasible candidate)."""
    sc, ws = tiny_start
    r = bn.smooth(sc, ws, method="sqp", alpha=1.0, interface="casadi")
    assert r.status == "converged" and bn.verify(sc, r.path).safe
    rows = r.history[1:]
    assert rows and all(h.min_margin != 0.0 for h in rows)
    assert 0.0 < rows[-1].min_margin < 1e-2 and rows[-1].kalman_gap < 1e-8      # an active row at the optimum
    assert sum(h.accepted for h in rows) > 1
    assert rows[-1].cost == pytest.approx(r.cost, rel=1e-6)


@pytest.mark.parametrize("interface", ["unopy", "casadi"])
def test_an_infeasible_stationary_point_is_rescued_by_funnel_sqp(interface):
    """cube3d at confidence 0.9 on the plan's own steps: filter-SQP's first
    attempt ends at an infeasible stationary point within a few iterations
    (session 19), and the warm start was returned. The restart from the start with
    Uno's funnel-SQP converges, verified, to IPOPT's optimum (a second
    solver), and the history runs on through both attempts."""
    if interface == "unopy" and not HAVE_UNOPY:
        pytest.skip("unopy is not installed (pip install -e '.[sqp]')")
    sc = bn.load_scenario("cube3d").with_options(confidence=0.9)
    plan = bn.plan(sc, seed=0, alpha=0.1)
    r = bn.smooth(sc, plan, method="sqp", alpha=0.1, interface=interface)
    assert r.status == "converged" and r.safe and bn.verify(sc, r.path).safe
    ipo = bn.smooth(sc, plan, method="ipopt", alpha=0.1)
    assert r.cost == pytest.approx(ipo.cost, rel=1e-3) and r.cost < r.initial_cost
    assert [h.iteration for h in r.history] == list(range(r.nit + 1))
