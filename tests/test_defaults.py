"""Defaults that compose: what a new user types first works on every built-in."""

from __future__ import annotations

import pytest

import belief_nlp as bn


@pytest.mark.parametrize("name, alpha", [("paper-multi", 0.1), ("paper-multi", 1.0), ("quad", None),
                                         ("tutorial", None), ("cube3d", None)])
def test_smooth_of_a_default_plan_works(name, alpha):
    sc = bn.load_scenario(name)
    kw = {} if alpha is None else {"alpha": alpha}
    planned = bn.plan(sc, n_nodes=300, seed=0, **kw)
    assert planned.success, planned.message
    res = bn.smooth(name, planned, max_iter=5, **kw)       # names and PlanResults are accepted as they are
    assert res.safe and res.cost <= res.initial_cost
    assert bn.verify(name, res).safe


def test_paper_multi_plans_with_the_smoothers_noise_model_and_a_radius_for_its_alpha():
    sc = bn.load_scenario("paper-multi")
    planner = bn.IGRRTStar(sc, alpha=1.0)
    assert planner.options.noise == "per_step"
    assert planner.options.max_radius + planner.options.radius_per_alpha * 1.0 == pytest.approx(1.5)
    assert bn.IGRRTStar(sc, noise="per_metre").options.noise == "per_metre"    # a keyword still wins
