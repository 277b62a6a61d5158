"""A re-plan from a new start belief reuses everything built for the scenario.

The start belief (x0, P0) is a parameter of every form generated from the
model (the NLP's p, the CCP step's parameters), not a constant: the cache
keys leave it out, and a solver or conic step built for one start answers
another exactly as one built for that start does. Checked against fresh
builds and against the model's numpy evaluation of the margins.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.allocation import RiskBudget
from belief_nlp.methods.ccp import conic_step_of, initial_rho
from belief_nlp.methods.nlp_build import clear_cache
from belief_nlp.model import BeliefModel
from belief_nlp.model.cache import MEMORY, problem_key
from belief_nlp.model.conic_form import conic_step
from belief_nlp.model.nlp_form import build_nlp

from conftest import PAPER_MULTI_WAYPOINTS, densify


def _start(x0, P0, steps: int = 2):
    """(paper-multi with start (x0, P0), the warm start of the hand route from x0)."""
    sc = bn.load_scenario("paper-multi").with_options(x0=np.asarray(x0, float), P0=np.asarray(P0, float))
    wp = PAPER_MULTI_WAYPOINTS.copy()
    wp[0] = x0
    x = densify(wp, steps)
    K = x.shape[0] - 1
    path = bn.BeliefPath.from_sensing(x, sc.P0, np.broadcast_to(1e4 * np.eye(2), (K, 2, 2)), W=sc.W)
    return sc, bn.warm_start(sc, path)


@pytest.fixture(scope="module")
def two_starts():
    """The paper's start and a moved one with a 1000x larger covariance (K = 10)."""
    return _start((0.15, 0.50), 1e-9 * np.eye(2)), _start((0.17, 0.47), 1e-6 * np.array([[1.0, 0.3], [0.3, 2.0]]))


def test_the_key_leaves_out_the_start_only(two_starts):
    (sc1, ws1), (sc2, ws2) = two_starts
    d1 = BeliefModel(sc1, ws1.K, 1.0).data
    d2 = BeliefModel(sc2, ws2.K, 0.3).data
    assert problem_key(d1, 1e-6, "s") == problem_key(d2, 1e-6, "s")
    other_w = BeliefModel(sc1.with_options(W=2 * sc1.W), ws1.K, 1.0).data
    other_chi2 = BeliefModel(sc1.with_options(chi2_value=sc1.chi2 + 1), ws1.K, 1.0).data
    assert len({problem_key(d, 1e-6, "s") for d in (d1, other_w, other_chi2)}) == 3


def test_nlp_built_for_one_start_has_the_rows_of_another(two_starts):
    """The NLP of start 1 read with start 2's model: its rows and cost parts
    are start 2's model margins and cost at random points (the k = 1 rows
    read x0 and P0)."""
    (sc1, ws1), (sc2, ws2) = two_starts
    m1, m2 = BeliefModel(sc1, ws1.K, 1.0), BeliefModel(sc2, ws2.K, 1.0)
    nlp = build_nlp(m1, "cholesky").for_model(m2)
    z = m2.tighten(m2.from_path(ws2.path, ws2.lam))
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = z.copy()
        q.x[1:] += 0.01 * rng.normal(size=q.x[1:].shape)
        q.lam = q.lam * np.exp(0.05 * rng.normal(size=q.lam.shape))
        q = m2.tighten(q)
        col, tgt = nlp.margin_values(nlp.pack(q))
        s, e = m2.transition_margins(q)
        np.testing.assert_allclose(col, np.stack([s, e], axis=-1).ravel(), rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(tgt, m2.target_margins(q), rtol=1e-8, atol=1e-9)
        ctrl, info, _ = (float(v) for v in nlp.parts(nlp.pack(q), nlp.anchor(q)))
        c2, ctrl2, info2 = m2.cost(q)
        assert ctrl == pytest.approx(ctrl2, rel=1e-9) and info == pytest.approx(info2, rel=1e-9, abs=1e-12)
        # start 1's own model reads other values at k = 1: the binding matters
        assert not np.allclose(build_nlp(m1, "cholesky").margin_values(nlp.pack(q))[0][:2], col[:2])
    assert np.array_equal(nlp.unpack(nlp.pack(z)).x[0], m2.data.x0)


@pytest.mark.parametrize("risk", [None, RiskBudget(0.05, allocation="uniform", kind="continuous")],
                         ids=["steps", "continuous"])
def test_conic_step_built_for_one_start_is_the_step_of_another(two_starts, risk):
    """The cached Clarabel data of start 1, read with start 2's layout, equal
    the data built from start 2's convex form (under a continuous-time
    budget too, whose transition 2 reads T2 = (P0 + 2 W)^-1)."""
    (sc1, ws1), (sc2, ws2) = two_starts
    m1, m2 = BeliefModel(sc1, ws1.K, 1.0, risk=risk), BeliefModel(sc2, ws2.K, 1.0, risk=risk)
    MEMORY.clear()
    first = conic_step_of(m1, cache_dir=False)
    reused = conic_step_of(m2, cache_dir=False)
    assert reused.fn is first.fn and reused.layout.data is m2.data
    fresh = conic_step(m2.convex_form)
    q = m2.tighten(m2.from_path(ws2.path, ws2.lam))
    rho = initial_rho(m2, q)
    for got, ref in zip(reused.data(q, rho, rho), fresh.data(q, rho, rho)):
        got, ref = (v.toarray() if hasattr(v, "toarray") else v for v in (got, ref))
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", ["ipopt", "ccp"])
def test_a_replan_from_a_new_start_reuses_the_build_and_answers_as_a_fresh_one(two_starts, method):
    (sc1, ws1), (sc2, ws2) = two_starts
    kw = {"method": method, "alpha": 1.0} | ({"max_iter": 3000} if method == "ipopt" else {})
    clear_cache()
    MEMORY.clear()
    bn.smooth(sc1, ws1, **kw)
    reused = bn.smooth(sc2, ws2, **kw)
    clear_cache()
    MEMORY.clear()
    fresh = bn.smooth(sc2, ws2, **kw)
    if method == "ipopt":
        assert reused.stats["build"] == "memory" and fresh.stats["build"] == "built"
    assert reused.status == fresh.status == "converged" and reused.safe
    assert bn.verify(sc2, reused.path).safe
    # (to rounding: the path comes back from the model's scaled units)
    np.testing.assert_allclose(reused.path.x[0], sc2.x0, rtol=1e-15, atol=0)
    np.testing.assert_allclose(reused.path.P[0], sc2.P0, rtol=1e-14, atol=0)
    assert reused.cost == pytest.approx(fresh.cost, rel=1e-8) and reused.nit == fresh.nit
    np.testing.assert_allclose(reused.path.x, fresh.path.x, rtol=0, atol=1e-8)


@pytest.fixture(scope="module")
def previous(two_starts):
    """IPOPT's answer from the paper's start (K = 10)."""
    (sc1, ws1), _ = two_starts
    return bn.smooth(sc1, ws1, method="ipopt", alpha=1.0, max_iter=3000)


def test_reanchor_keeps_the_means_and_sensing_from_the_new_start(two_starts, previous):
    _, (sc2, _) = two_starts
    for advance in (0, 1, 3):
        p = bn.reanchor(sc2, previous, advance=advance)
        assert p.K == previous.path.K - advance
        np.testing.assert_array_equal(p.x[0], sc2.x0)
        np.testing.assert_array_equal(p.x[1:], previous.path.x[advance + 1:])
        np.testing.assert_array_equal(p.S[1:], previous.path.S[advance + 1:])
        np.testing.assert_array_equal(p.P[0], sc2.P0)
        # the Kalman recursion from the new P0 (Lemma 2), computed here by hand
        P1 = np.linalg.inv(np.linalg.inv(sc2.P0 + sc2.W) + p.S[1])
        np.testing.assert_allclose(p.P[1], P1, rtol=1e-9, atol=1e-15)


def test_replan_is_the_reanchored_smooth_and_reuses_the_build(two_starts, previous):
    """replan = smooth of the re-anchored path with its sensing kept; on the
    same scenario and K nothing is built; the answer is verified, starts at
    the new belief and is no costlier than its warm start."""
    (sc1, _), _ = two_starts
    sc2 = sc1.with_options(x0=sc1.x0 + np.array([1e-3, -2e-3]), P0=4e-9 * np.eye(2))    # the robot's new belief
    kw = {"method": "ipopt", "alpha": 1.0, "max_iter": 3000}
    r = bn.replan(sc2, previous, **kw)
    ref = bn.smooth(sc2, bn.reanchor(sc2, previous), sensing="path", resume=previous.resume, **kw)
    assert r.status == "converged" and r.safe and bn.verify(sc2, r.path).safe
    # the graph and its derivatives are the scenario's (the resumed stage's
    # solver, with its own options, is given them: nothing derived again)
    assert r.stats["build"] in ("memory", "built (derivatives shared)")
    assert r.cost == ref.cost and r.nit == ref.nit
    assert r.path.K == previous.path.K and r.cost <= r.initial_cost
    np.testing.assert_allclose(r.path.x[0], sc2.x0, rtol=1e-15, atol=0)
    np.testing.assert_allclose(r.path.P[0], sc2.P0, rtol=1e-14, atol=0)
    # two steps executed: the robot is near the previous plan's step-2 belief
    moved = sc1.with_options(x0=previous.path.x[2] + np.array([-1e-3, 0.0]), P0=previous.path.P[2])
    shorter = bn.replan(moved, previous, advance=2, **kw)
    assert shorter.status == "converged" and shorter.path.K == previous.path.K - 2
    assert bn.verify(moved, shorter.path).safe


@pytest.mark.parametrize("kwargs, field", [({"advance": -1}, "advance"), ({"advance": 10}, "advance"),
                                           ({"advance": 1.0}, "advance"), ({"advance": True}, "advance"),
                                           ({"K": 8}, "K"), ({"sensing": "minimal"}, "sensing")])
def test_replan_bad_arguments_are_named(two_starts, previous, kwargs, field):
    _, (sc2, _) = two_starts
    with pytest.raises(bn.ValidationError) as err:
        bn.replan(sc2, previous, **kwargs)
    assert err.value.field == field
    with pytest.raises(bn.ValidationError) as err:
        bn.replan(sc2, "last plan")
    assert err.value.field == "previous"


def test_replan_from_a_start_the_first_step_cannot_leave_is_refused(two_starts, previous):
    """From (0.17, 0.47) the previous plan's third mean lies behind obstacle 2
    (as if two steps were done but the robot had not moved): the re-anchored
    start is refused, naming the transition and the obstacle."""
    _, (sc2, _) = two_starts
    with pytest.raises(bn.InfeasibleStartError) as err:
        bn.replan(sc2, previous, advance=2, method="ipopt")
    assert err.value.transition == 1 and err.value.obstacle == "obstacle 2"


def test_replan_resumes_ipopt_from_the_last_answers_variables_and_multipliers(two_starts, previous):
    """The last answer's first-stage state (SmoothResult.resume) starts the
    re-plan's first stage: the same answer as the re-plan from the path
    alone (cost to 1e-6), in fewer iterations here (K = 10: the state is
    4-8 IPOPT iterations from the new optimum)."""
    (sc1, _), _ = two_starts
    sc2 = sc1.with_options(x0=sc1.x0 + np.array([1e-3, -2e-3]), P0=4e-9 * np.eye(2))
    res = previous.resume
    assert res is not None and res["z"].size == res["lam_x"].size and res["lam_g"].size > 0
    kw = {"method": "ipopt", "alpha": 1.0, "max_iter": 3000}
    resumed = bn.replan(sc2, previous, **kw)
    plain = bn.replan(sc2, dataclasses.replace(previous, resume=None), **kw)
    assert resumed.stats["resumed"] == "yes" and plain.stats["resumed"] == "no"
    assert resumed.status == "converged" and resumed.safe and bn.verify(sc2, resumed.path).safe
    assert resumed.cost == pytest.approx(plain.cost, rel=1e-6)
    assert resumed.nit < plain.nit
    assert resumed.resume is not None                  # a loop re-plans again from this one
    # auto hands it to its IPOPT stage
    auto = bn.replan(sc2, bn.smooth(sc1, previous.path, method="auto", alpha=1.0), alpha=1.0)
    assert auto.stats["ipopt"]["resumed"] == "yes" and auto.safe


def test_a_resumed_stage_that_fails_falls_back_to_the_usual_first_stage(two_starts, previous, resume_fails):
    """When the resumed solve does not end converged and exactly safe, the
    usual first stage runs from the warm start: the run converges, verified,
    with both solves in its stats (the resumed attempt first). The usual
    stage may restart once inside the Kalman box: from this start (the last
    answer, already polished) its floored answer converges 0.1 % above it."""
    (sc1, _), _ = two_starts
    sc2 = sc1.with_options(x0=sc1.x0 + np.array([1e-3, -2e-3]))
    r = bn.replan(sc2, previous, method="ipopt", alpha=1.0, max_iter=3000)
    assert r.stats["resumed"] == "fell back" and r.status == "converged" and r.safe
    plain = bn.replan(sc2, dataclasses.replace(previous, resume=None), method="ipopt", alpha=1.0, max_iter=3000)
    first_stage = ([a["iter_count"] for a in x.stats["attempts"] if a["formulation"] == "logchol"] for x in (r, plain))
    resumed_and_usual, usual = first_stage
    assert len(resumed_and_usual) >= 2 and resumed_and_usual[1:] == usual       # the resumed attempt, then the usual
    assert r.cost == pytest.approx(plain.cost, rel=1e-6)


def test_a_resume_state_from_another_graph_is_not_used(two_starts, previous):
    (sc1, ws1), _ = two_starts
    other = {**previous.resume, "floor": 3e-3}
    r = bn.smooth(sc1, ws1, method="ipopt", alpha=1.0, resume=other)
    assert r.stats["resumed"] == "does not fit" and r.status == "converged"
    with pytest.raises(bn.ValidationError) as err:
        bn.smooth(sc1, ws1, method="ipopt", resume={"z": [1.0]})
    assert err.value.field == "resume"


def test_the_resume_state_is_not_saved(previous, tmp_path):
    back = bn.SmoothResult.load(previous.save(tmp_path / "r.json"))
    assert back.resume is None and back == previous


def test_replan_with_auto_options_of_the_wrong_type_is_our_error(two_starts, previous):
    (sc1, _), _ = two_starts
    sc2 = sc1.with_options(x0=sc1.x0 + np.array([1e-3, -2e-3]))
    with pytest.raises(bn.ValidationError) as err:
        bn.replan(sc2, previous, method="auto", ipopt_options="fast")
    assert err.value.field == "ipopt_options"
