"""The OMPL baseline: plan(planner="ompl:<Class>"), its exact validity checks, errors, studies.

Tests that run OMPL skip when the ``ompl`` package (the ``ompl`` extra) is not
importable; the test extra installs it, so CI runs them.
"""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.geometry import PolytopeSet, containment_margin, transition_minimiser
from belief_nlp.planner.ompl_baseline import MeanPathValidity

HAS_OMPL = importlib.util.find_spec("ompl") is not None
needs_ompl = pytest.mark.skipif(not HAS_OMPL, reason="the OMPL baseline needs the 'ompl' extra "
                                                     "(pip install 'belief-nlp[ompl]'); not installed here")


@pytest.fixture(scope="module")
def sc():
    return bn.load_scenario("paper-multi")


@pytest.fixture(scope="module")
def ompl_plan(sc):
    # 2 s: RRT* finds paper-multi's first path in 0.1-1 s here (Python validity callbacks)
    return bn.plan(sc, planner="ompl:RRTstar", time_limit=2.0, alpha=0.1, goal_bias=0.1)


# ------------------------------------------------------------ validity checks
def test_motion_validity_agrees_with_the_exact_minimiser(sc):
    """The planner's layered checker (what OMPL is given) against the plain Theorem-1
    minimiser of geometry/, on random segments, both directions, from the floor covariance."""
    v = MeanPathValidity(sc, 1e-6)
    hazards = PolytopeSet.build(sc.hazards)
    thr = sc.chi2 * (1 + 1e-6)
    rng = np.random.default_rng(3)
    a = rng.uniform(0.02, 0.98, (150, 2))
    b = np.clip(a + rng.normal(0, 0.15, a.shape), 0.02, 0.98)
    agree = decided = 0
    for p, q in zip(a, b):
        got = v.motion_valid(p, q)
        lows = [transition_minimiser(s, v.P_floor, e, sc.W, hazards, threshold=thr) for s, e in ((p, q), (q, p))]
        want = all(np.all(t.lower >= thr) for t in lows)
        maybe = any(np.any((t.lower < thr) & (t.dist2 >= thr)) for t in lows)   # bounds undecided
        if not maybe:
            decided += 1
            agree += got == want
        else:
            assert not got or want  # an undecided pair is never accepted
    assert decided >= 140 and agree == decided
    assert 20 < v.stats["motions_valid"] < 140     # both kinds of segments occur


def test_motions_from_the_start_use_its_covariance(sc):
    v = MeanPathValidity(sc, 1e-6)
    # a state is valid only where a step can end: one step's noise W must fit (here near the wall y = 0)
    r = np.sqrt(sc.chi2 * np.max(np.linalg.eigvalsh(sc.W)))
    assert v.state_valid(np.array([0.65, 1.01 * r])) and not v.state_valid(np.array([0.65, 0.99 * r]))
    x0 = np.asarray(sc.x0, float)
    q = x0 + np.array([0.05, 0.0])
    assert v.motion_valid(x0, q) and v.motion_valid(q, x0)
    assert v.state_valid(x0)
    inside = np.array([0.33, 0.35])           # inside obstacle 4 of paper-multi
    assert not v.state_valid(inside) and not v.motion_valid(x0, inside)
    assert v.in_target(np.array([0.65, 0.05])) and not v.in_target(np.array([0.6, 0.05]))


# ------------------------------------------------------------------ planning
@needs_ompl
def test_rrtstar_plan_is_verified_and_minimally_sensed(sc, ompl_plan):
    res = ompl_plan
    assert res.success, res.message
    assert res.planner == "ompl:RRTstar" and res.noise == "per_step" and res.tree is None
    path = res.path
    assert np.allclose(path.x[0], sc.x0) and bn.verify(sc, path).safe       # independent verifier
    assert res.cost == pytest.approx(path.planner_cost(0.1)) and res.travel == pytest.approx(path.length)
    # the anytime curve: increasing times, non-increasing OMPL cost, ending at the path's length
    t = [p[0] for p in res.cost_trace]
    c = [p[1] for p in res.cost_trace]
    assert t == sorted(t) and all(x >= y - 1e-12 for x, y in zip(c, c[1:]))
    assert c[-1] == pytest.approx(path.length, rel=1e-9) and t[-1] <= res.timings["total"]
    # least sensing (up to one halving): steps without a need sense nothing, and half as much
    # sensing (twice the posterior) at a sensing step breaks the next transition or the target
    hazards = PolytopeSet.build(sc.hazards)
    thr = sc.chi2 * (1 + 1e-6)
    sensing = set(path.sensing_steps.tolist())
    assert sensing, "paper-multi needs sensing"
    for k in range(1, path.K + 1):
        if k not in sensing:
            assert np.allclose(path.P[k], path.P_prior[k], rtol=1e-12, atol=0)
            continue
        P2 = 2 * path.P[k]
        if k < path.K:
            broke = np.any(transition_minimiser(path.x[k], P2, path.x[k + 1], sc.W, hazards).dist2 < thr)
        else:
            broke = containment_margin(path.x[k], P2, sc.target.A, sc.target.b, sc.chi2) < 1e-9
        halving_more = np.all(np.linalg.eigvalsh(path.P_prior[k] - P2) >= -1e-15)
        assert broke or not halving_more, f"step {k} senses more than needed"


@needs_ompl
def test_ompl_plan_smooths_like_any_plan(sc, ompl_plan):
    res = bn.smooth(sc, ompl_plan.path, method="ccp", max_iter=2, alpha=0.1)
    assert res.safe and res.cost <= res.initial_cost + 1e-12
    assert bn.verify(sc, res.path).safe


@needs_ompl
def test_plan_result_round_trips_with_planner_and_trace(tmp_path, ompl_plan):
    for suffix in ("json", "npz"):
        f = ompl_plan.save(tmp_path / f"p.{suffix}")
        back = bn.PlanResult.load(f)
        assert back == ompl_plan and back.planner == "ompl:RRTstar" and back.cost_trace == ompl_plan.cost_trace
    assert "ompl:RRTstar success" in ompl_plan.summary()


@needs_ompl
@pytest.mark.parametrize("name", ["ompl:InformedRRTstar", "ompl:AORRTC", "ompl:RRTConnect"])
def test_other_named_planners(sc, name):
    res = bn.plan(sc, planner=name, time_limit=1.5, alpha=1.0)
    assert res.planner == name
    if res.success:       # time-bounded: a miss is reported, never an unsafe path
        assert bn.verify(sc, res.path).safe and res.alpha == 1.0
    else:                 # no path in time, or a mean path no sensing can make safe (CPU-dependent)
        assert "no exact solution" in res.message or "cannot carry a safe belief" in res.message


# -------------------------------------------------------------------- errors
@pytest.mark.parametrize("name", ["rrt", "RRTstar", 3, "ompl:", "ompl:NoSuchPlanner"])
def test_bad_planner_names_name_the_field(sc, name):
    if isinstance(name, str) and name.startswith("ompl:") and not HAS_OMPL:
        pytest.skip("checking OMPL names needs the 'ompl' extra")
    with pytest.raises(bn.ValidationError) as err:
        bn.plan(sc, planner=name)
    assert err.value.field == "planner"


@needs_ompl
def test_threaded_planners_are_refused(sc):
    with pytest.raises(bn.ValidationError, match="threads") as err:
        bn.plan(sc, planner="ompl:PRMstar")
    assert err.value.field == "planner"


@needs_ompl
@pytest.mark.parametrize("kw, field", [({"n_nodes": 100}, "n_nodes"), ({"noise": "per_metre"}, "noise"),
                                       ({"max_radius": 0.3}, "max_radius"), ({"time_limit": 0}, "time_limit"),
                                       ({"metric": "hellinger"}, "metric"), ({"range": -1.0}, "range"),
                                       ({"alpha": 1e300}, "alpha"), ({"seed": -1}, "seed")])
def test_bad_ompl_options_name_the_field(sc, kw, field):
    with pytest.raises(bn.ValidationError) as err:
        bn.plan(sc, planner="ompl:RRTstar", **kw)
    assert err.value.field == field


def test_missing_ompl_says_to_install_the_extra(sc, monkeypatch):
    monkeypatch.setitem(sys.modules, "ompl", None)      # import ompl now raises ImportError
    with pytest.raises(bn.SolverError, match=r"belief-nlp\[ompl\]"):
        bn.plan(sc, planner="ompl:RRTstar")


def test_default_planner_is_igrrt(sc):
    res = bn.plan(sc, n_nodes=40, seed=1, planner="igrrt")
    assert res.planner == "igrrt" and res.tree is not None
    assert all(a[0] <= b[0] and a[1] >= b[1] for a, b in zip(res.cost_trace, res.cost_trace[1:]))
    if res.success:
        assert res.cost_trace[-1][1] == pytest.approx(res.cost)


# ------------------------------------------------------------------- studies
@needs_ompl
def test_planner_name_in_a_study_file():
    study = bn.study.load_study({"study": {"name": "b", "scenarios": ["paper-multi"], "seeds": [0], "alpha": [0.1],
                                           "K": [0], "methods": ["none"]},
                                 "planner": {"planner": "ompl:RRTstar", "time_limit": 2.0, "goal_bias": 0.1}})
    (case,) = list(study.cases())
    (row,) = bn.study.run_case(case)
    assert row["planner_name"] == "ompl:RRTstar" and row["status"] == "warm_start", row["message"]
    trace = json.loads(row["plan_trace"])
    assert trace and trace[-1][0] <= row["plan_time"]
    assert row["safe"] and row["cost"] == pytest.approx(row["warm_start_cost"])


@needs_ompl
def test_planner_names_are_case_insensitive():
    from belief_nlp.planner.ompl_baseline import parse_planner

    assert parse_planner("OMPL:rrtstar") == "RRTstar" and parse_planner("IGRRT") is None
