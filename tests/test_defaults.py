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
    assert res.method.startswith("auto")                    # no method named: the default, auto


def test_auto_is_the_default_method_and_listed_first():
    assert bn.DEFAULT_METHOD == bn.smoother.DEFAULT_METHOD == "auto"
    names = bn.available_methods()
    assert names[0] == "auto" and "ccp" in names and "ipopt" in names
    assert len(set(names)) == len(names)
    import inspect

    assert inspect.signature(bn.smooth).parameters["method"].default == "auto"


def test_smooth_without_a_method_runs_auto():
    from conftest import paper_multi_path_pair

    sc, path = paper_multi_path_pair(steps_per_segment=1)        # K = 5
    res = bn.smooth(sc, path, alpha=1.0)
    assert res.method.startswith("auto") and res.method in ("auto:ipopt", "auto:ccp", "auto:ipopt+ccp")
    assert res.stats["stages"][0] == "ipopt"
    assert res.safe and res.cost <= res.initial_cost
    assert bn.verify(sc, res).safe


def test_paper_multi_plans_with_the_smoothers_noise_model_and_a_radius_for_its_alpha():
    sc = bn.load_scenario("paper-multi")
    planner = bn.IGRRTStar(sc, alpha=1.0)
    assert planner.options.noise == "per_step"
    assert planner.options.max_radius + planner.options.radius_per_alpha * 1.0 == pytest.approx(1.5)
    assert bn.IGRRTStar(sc, noise="per_metre").options.noise == "per_metre"    # a keyword still wins


@pytest.mark.parametrize("name", ["tutorial", "quad", "cube3d"])
def test_every_builtin_plans_with_per_step_noise_at_the_papers_alphas(name):
    # with a fixed rewiring cap, per-step noise left no edge cheap enough at
    # alpha = 1 on these three (one unsensed step costs ~alpha/2 log det(I + W P^-1)
    # whatever its length): "no path ... (node budget reached)" for every seed
    sc = bn.load_scenario(name)
    for alpha in (0.1, 1.0):
        planned = bn.plan(sc, n_nodes=500, seed=0, alpha=alpha, noise="per_step")
        assert planned.success, (alpha, planned.message)
        assert bn.verify(sc, planned.path).safe


def test_the_rewiring_cap_grows_with_alpha_under_per_step_noise_unless_set():
    from belief_nlp.planner.options import PER_STEP_RADIUS_PER_ALPHA, resolve_options

    assert resolve_options({}, 1.0, noise="per_step").radius_per_alpha == PER_STEP_RADIUS_PER_ALPHA > 0
    assert resolve_options({}, 1.0, noise="per_metre").radius_per_alpha == 0.0   # shrinks with the edge
    assert resolve_options({"radius_per_alpha": 0.0}, 1.0, noise="per_step").radius_per_alpha == 0.0
    assert resolve_options({}, 1.0, noise="per_step", radius_per_alpha=2.0).radius_per_alpha == 2.0
    with pytest.raises(bn.errors.ValidationError, match="radius_per_alpha"):
        resolve_options({}, 1.0, radius_per_alpha=-1.0)


def test_plan_results_are_taken_as_their_path_and_a_failed_one_says_why():
    sc = bn.load_scenario("tutorial")
    planned = bn.plan(sc, n_nodes=300, seed=0)
    assert planned.success
    ws = bn.warm_start(sc, planned)                       # was "path: must be a BeliefPath, got PlanResult"
    assert ws.path == bn.warm_start(sc, planned.path).path
    failed = bn.plan(sc, n_nodes=2, seed=0)                # two nodes cannot reach the target
    assert not failed.success
    for call in (lambda: bn.warm_start(sc, failed), lambda: bn.smooth(sc, failed), lambda: bn.verify(sc, failed)):
        with pytest.raises(bn.errors.ValidationError, match="the PlanResult holds no path") as exc:
            call()
        assert failed.message in str(exc.value)
