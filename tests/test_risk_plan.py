"""``plan(..., risk=Delta)``: IG-RRT* within an end-to-end collision budget
(issue 20, item 3). Every bound is recomputed from the returned path by
:func:`belief_nlp.risk.path_risk`, independently of the planner's decisions."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.allocation import RiskBudget, tail
from belief_nlp.errors import ValidationError
from belief_nlp.planner import PlanResult, budget as budget_mod
from belief_nlp.planner.collision import CollisionChecker
from belief_nlp.risk import path_risk

NODES = 200


@pytest.fixture(scope="module")
def paper():
    return bn.load_scenario("paper-multi")


@pytest.fixture(scope="module")
def plans(paper):
    """Plans of the same seed at two budgets."""
    return {d: bn.plan(paper, n_nodes=NODES, seed=0, risk=d) for d in (0.01, 0.05)}


def test_plan_meets_the_budget_by_an_independent_bound(paper, plans):
    res = plans[0.05]
    assert res.success, res.message
    bound = path_risk(paper, res.path)
    assert bound.step_time <= 0.05
    assert res.risk["bound"] == pytest.approx(bound.step_time, rel=1e-12)
    assert res.risk["budget"] == 0.05 and res.risk["met"] and res.risk["kind"] == "steps"
    # the planner kept every pair clear at its collision level (rigorous clearances of the path)
    level = res.risk["collision_chi2"]
    assert level == res.options["collision_chi2"] > paper.chi2
    assert np.min(bound.clearance) >= level * (1 - 1e-6)
    # ... and the target at the scenario's own level: verify at the scenario's chi2 passes
    rep = bn.verify(paper, res.path)
    assert rep.safe, rep.summary()
    assert "risk budget 0.05" in res.message or "risk budget 0.05" in res.summary()


def _fewest_edges(sc) -> int:
    """Edges of length <= the rewiring cap from the start mean to the target (a box)."""
    cap = sc.planner["max_radius"] + sc.planner["radius_per_alpha"] * sc.alpha
    lo, hi = sc.target.bounding_box()
    return math.ceil(math.dist(sc.x0, np.clip(sc.x0, lo, hi)) / cap)


def test_level_is_the_smoothers_warm_start_level(paper, plans):
    """paper-multi smooths at its horizon K = 20, so the plan's level is the
    smoother's warm start level g^-1(0.9 Delta / (20 J)), and the plan (K <=
    20) is taken in the first round."""
    res = plans[0.05]
    J = len(paper.hazards)
    assert paper.K == 20 > _fewest_edges(paper) and res.path.K <= paper.K
    (r,) = res.risk["rounds"]
    assert r["n_pairs"] == r["pairs_needed"] == J * paper.K
    assert tail(r["collision_chi2"]) == pytest.approx(0.9 * 0.05 / (J * paper.K), rel=1e-9)
    assert r["collision_chi2"] == pytest.approx(RiskBudget(0.05).warm_level(J * paper.K))


def test_tighter_budget_certifies_less(plans):
    tight, loose = plans[0.01], plans[0.05]
    assert tight.success and loose.success
    assert tight.risk["bound"] <= 0.01
    assert tight.risk["collision_chi2"] > loose.risk["collision_chi2"]
    assert tight.risk["bound"] < loose.risk["bound"]


@pytest.mark.parametrize("seed", [0, 2])
def test_without_a_horizon_the_rounds_follow_the_paths_edges(paper, seed):
    """No horizon: the smoother takes one step per edge. Round 1 assumes the
    fewest edges (at Delta = 0.45 its level is below chi2, so chi2 is kept);
    each next round covers the last path's pairs, until a path's pairs are
    covered by its own level."""
    sc = paper.with_options(K=None)
    J = len(sc.hazards)
    res = bn.plan(sc, n_nodes=NODES, seed=seed, risk=0.45)
    rounds = res.risk["rounds"]
    assert res.success and len(rounds) >= 2
    assert rounds[0]["n_pairs"] == J * _fewest_edges(sc) and rounds[0]["collision_chi2"] == sc.chi2
    for prev, nxt in zip(rounds, rounds[1:]):
        assert prev["pairs_needed"] == J * prev["K"] > prev["n_pairs"] or prev["bound"] > 0.45
        assert nxt["n_pairs"] == budget_mod._next_pairs(prev["n_pairs"], prev["pairs_needed"])
        assert nxt["collision_chi2"] > prev["collision_chi2"]
    last = rounds[-1]
    assert J * res.path.K == last["pairs_needed"] <= last["n_pairs"]
    assert last["collision_chi2"] == pytest.approx(RiskBudget(0.45).warm_level(last["n_pairs"]))
    assert path_risk(sc, res.path).step_time == pytest.approx(last["bound"]) and last["bound"] <= 0.45


def test_scenario_risk_is_the_default_and_the_argument_wins(paper, plans):
    with_budget = paper.with_options(risk=0.05)
    res = bn.plan(with_budget, n_nodes=NODES, seed=0)
    assert res.risk["budget"] == 0.05
    assert np.array_equal(res.path.x, plans[0.05].path.x)
    over = bn.plan(with_budget, n_nodes=NODES, seed=0, risk=0.01)
    assert over.risk["budget"] == 0.01 and np.array_equal(over.path.x, plans[0.01].path.x)
    # no budget: the fixed level, no risk record
    plain = bn.plan(paper, n_nodes=NODES, seed=0)
    assert plain.risk is None and plain.options["collision_chi2"] is None


@pytest.mark.parametrize("bad", [0, 0.0, -0.1, 0.5, 0.9, 1.0, math.nan, math.inf, True, "0.05", [0.05]])
def test_bad_budgets_are_refused(paper, bad):
    with pytest.raises(ValidationError) as info:
        bn.plan(paper, n_nodes=NODES, risk=bad)
    assert info.value.field == "risk"


def test_a_budget_the_start_already_spends_is_refused(paper):
    # P0 = 2e-3 I: the start is 5.0 Mahalanobis^2 from obstacle 1 (clear at chi2 = 4.6), so the start
    # alone certifies no less than g(5.0) = 0.0127 over that pair
    wide = paper.with_options(P0=2e-3 * np.eye(2))
    with pytest.raises(ValidationError) as info:
        bn.plan(wide, n_nodes=NODES, risk=0.01)
    assert info.value.field == "risk" and "start belief" in str(info.value)
    spent = float(np.sum(tail(bn.geometry.squared_mahalanobis_distance(wide.x0, wide.P0, list(wide.hazards)))))
    assert 0.01 < spent < 0.02
    assert wide.with_options(risk=0.02).risk == 0.02                          # a larger budget is taken


def test_ompl_planners_refuse_a_budget(paper):
    pytest.importorskip("ompl")
    for sc, kw in ((paper, {"risk": 0.05}), (paper.with_options(risk=0.05), {})):
        with pytest.raises(ValidationError) as info:
            bn.plan(sc, planner="ompl:RRTstar", time_limit=0.1, **kw)
        assert info.value.field == "risk"


def test_collision_level_option_is_checked(paper):
    with pytest.raises(ValidationError) as info:
        bn.plan(paper, n_nodes=NODES, risk=0.05, collision_chi2=10.0)
    assert info.value.field == "collision_chi2"
    with pytest.raises(ValidationError) as info:
        bn.plan(paper, n_nodes=NODES, collision_chi2=paper.chi2 / 2)          # below the target's level
    assert info.value.field == "collision_chi2"


def test_checker_keeps_the_target_at_the_scenario_level(paper):
    """An ellipse inside the target at chi2 = 4.6 but not at 20: the target
    verdict follows the scenario's chi2 whatever the collision level."""
    x, P = np.array([0.65, 0.05]), 2.5e-4 * np.eye(2)           # 0.05 m to each face: d^2 = 10
    high = CollisionChecker(paper, 1e-6, chi2=20.0)
    assert high.in_target(x, P) and CollisionChecker(paper, 1e-6).in_target(x, P)
    assert not CollisionChecker(paper.with_options(chi2_value=20.0), 1e-6).in_target(x, P)
    # the collisions follow the level: an ellipse 10 Mahalanobis^2 from the nearest hazard is clear
    # at 4.6 and needs sensing (a shrink) at 20
    assert CollisionChecker(paper, 1e-6).shrink_exponent(x, P) == 0
    assert high.shrink_exponent(x, P) > 0


def test_next_round_pair_count():
    assert budget_mod._next_pairs(20, 70) == 70                             # the last path's pairs
    assert budget_mod._next_pairs(200, 200) == 250                          # at least 1.25 x
    assert budget_mod._next_pairs(200, 100) == 250


def test_rounds_raise_the_level_until_the_bound_fits(paper, monkeypatch):
    """A first path reported over the budget makes a second round at a
    higher level; the answer's bound is the real one."""
    real = budget_mod._certified_bound
    calls = []

    def first_over(sc, res):
        calls.append(res.path.K)
        return 2 * 0.05 if len(calls) == 1 else real(sc, res)

    monkeypatch.setattr(budget_mod, "_certified_bound", first_over)
    res = bn.plan(paper, n_nodes=NODES, seed=0, risk=0.05)
    r1, r2 = res.risk["rounds"]
    assert res.success and r1["bound"] == 0.1
    assert r2["n_pairs"] == budget_mod._next_pairs(r1["n_pairs"], r1["pairs_needed"]) == 250
    assert r2["collision_chi2"] > r1["collision_chi2"] and len(calls) == 2
    assert res.risk["bound"] == r2["bound"] == pytest.approx(path_risk(paper, res.path).step_time)
    assert res.options["collision_chi2"] == r2["collision_chi2"]


def test_no_plan_within_the_budget_is_a_failure(paper, monkeypatch):
    monkeypatch.setattr(budget_mod, "_certified_bound", lambda sc, res: 0.3)
    res = bn.plan(paper, n_nodes=150, seed=0, risk=0.05)
    assert not res.success and res.path is None and math.isinf(res.cost)
    assert "no plan within the risk budget 0.05" in res.message
    rounds = res.risk["rounds"]
    assert len(rounds) == budget_mod.MAX_ROUNDS and not res.risk["met"] and res.risk["bound"] is None
    levels = [r["collision_chi2"] for r in rounds]
    assert levels == sorted(levels) and len(set(levels)) == len(levels)


def test_no_path_found_ends_the_search(paper):
    res = bn.plan(paper, n_nodes=2, seed=0, risk=0.05)
    assert not res.success and "no plan within the risk budget 0.05" in res.message
    assert "no path" in res.message and len(res.risk["rounds"]) == 1 and not res.risk["rounds"][0]["found"]


@pytest.mark.parametrize("suffix", ["json", "npz"])
def test_result_round_trip_keeps_the_budget(plans, tmp_path, suffix):
    res = plans[0.05]
    back = PlanResult.load(res.save(tmp_path / f"plan.{suffix}"))
    assert back == res and back.risk == res.risk
    assert PlanResult.from_dict(json.loads(json.dumps(res.to_dict()))).risk == res.risk
    assert "risk budget 0.05" in back.summary()
    for bad, field in (([1, 2], "risk"), ({**res.risk, "budget": "x"}, "risk.budget"),
                       ({**res.risk, "bound": math.nan}, "risk.bound"), ({**res.risk, "rounds": 3}, "risk.rounds")):
        with pytest.raises(ValidationError) as info:
            PlanResult.from_dict({**res.to_dict(), "risk": bad})
        assert info.value.field == field
