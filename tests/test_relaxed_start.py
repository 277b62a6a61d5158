"""A start held to its own level (``Scenario.start_confidence``,
``bn.relaxed_start``): re-planning from an estimate that no plan can clear
at the scenario's level.

The case: paper-multi, a K = 20 plan, and the robot one step on but with
its estimate moved toward the nearest hazard until its ellipse touches it
at 0.7 chi2. Checked against independent computations: the clearances by
dense sampling of the hazard's boundary and of the first transition, and
every answer by ``bn.verify`` at the levels the scenario states.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2 as chi2_law

import belief_nlp as bn
from belief_nlp.errors import ScenarioFileError
from belief_nlp.model import BeliefModel
from belief_nlp.model.cache import problem_key
from belief_nlp.model.nlp_form import build_nlp, start_values
from belief_nlp.model.nlp_prefix import frozen


def _sampled_d2(x, P, poly, n=4000) -> float:
    """min over dense points of a 2-D polygon's boundary of (y - x)^T P^-1 (y - x)
    (an upper bound on the exact clearance, tight to the sampling)."""
    V = np.asarray(poly.vertices, float)
    c = V.mean(axis=0)
    V = V[np.argsort(np.arctan2(V[:, 1] - c[1], V[:, 0] - c[0]))]
    t = np.linspace(0, 1, n)[:, None]
    pts = np.vstack([V[i] + t * (V[(i + 1) % len(V)] - V[i]) for i in range(len(V))])
    d = pts - x
    return float(np.min(np.einsum("ni,ij,nj->n", d, np.linalg.inv(P), d)))


@pytest.fixture(scope="module")
def case():
    """(scenario, auto's K = 20 answer, the moved estimate x, its covariance P)."""
    sc = bn.load_scenario("paper-multi")
    plan = bn.plan(sc, n_nodes=500, seed=0, noise="per_step")
    res = bn.smooth(sc, plan.path, K=20, alpha=0.1)
    x1, P1 = res.path.x[1], res.path.P[1]
    hz = bn.geometry.PolytopeSet.cached(sc.hazards)
    j = int(np.argmin(bn.geometry.squared_mahalanobis_distance(x1[None], P1[None], hz)[0]))
    centre = sc.hazards[j].vertices.mean(axis=0)
    lo, hi = 0.0, 1.0                                   # move toward hazard j until d2 = 0.7 chi2
    for _ in range(60):
        t = 0.5 * (lo + hi)
        d2 = bn.geometry.squared_mahalanobis_distance((x1 + t * (centre - x1))[None], P1[None], hz)[0].min()
        lo, hi = (t, hi) if d2 > 0.7 * sc.chi2 else (lo, t)
    return sc, res, x1 + lo * (centre - x1), P1, j


def test_the_estimate_is_refused_at_the_scenarios_level(case):
    sc, _, x, P, j = case
    with pytest.raises(bn.ValidationError, match=f"not clear of {sc.hazards[j].name}.*relaxed_start"):
        sc.with_options(x0=x, P0=P)


def test_the_start_level_is_the_sampled_clearance_less_the_margin(case):
    sc, _, x, P, j = case
    now = bn.relaxed_start(sc, x, P)
    d2 = _sampled_d2(x, P, sc.hazards[j])
    assert abs(d2 / sc.chi2 - 0.7) < 1e-3                 # the fixture's own construction, sampled
    assert now.chi2_start == pytest.approx(0.98 * d2, rel=1e-4)
    assert now.start_confidence == pytest.approx(chi2_law.cdf(now.chi2_start, 2), rel=1e-9)
    assert now.chi2 == sc.chi2 and np.array_equal(now.x0, x)


def test_with_the_previous_plan_the_level_covers_its_first_step(case):
    sc, res, x, P, _ = case
    now = bn.relaxed_start(sc, x, P, previous=res, advance=1)
    # the re-anchored first transition: x -> the plan's x_2 under P(s) = P + s W, sampled densely
    x2 = res.path.x[2]
    worst = min(_sampled_d2(x + s * (x2 - x), P + s * sc.W, h)
                for s in np.linspace(0, 1, 201) for h in sc.obstacles)
    assert now.chi2_start <= 0.98 * worst * (1 + 1e-3)
    assert now.chi2_start < bn.relaxed_start(sc, x, P).chi2_start      # the step passes closer than the start


def test_a_clear_start_is_left_at_the_scenarios_level(case):
    sc, res, _, _, _ = case
    now = bn.relaxed_start(sc, res.path.x[1], res.path.P[1], previous=res, advance=1)
    assert now.start_confidence is None and now.chi2_start == sc.chi2


@pytest.mark.parametrize("method", ["auto", "ccp", "sqp"])
def test_a_replan_from_the_estimate_is_certified_at_the_levels_it_states(case, method):
    sc, res, x, P, _ = case
    with pytest.raises(bn.ValidationError):        # at the scenario's level there is nothing to re-plan from
        sc.with_options(x0=x, P0=P)
    now = bn.relaxed_start(sc, x, P, previous=res, advance=1)
    nxt = bn.replan(now, res, advance=1, method=method)
    assert nxt.success and nxt.cost <= nxt.initial_cost
    rep = bn.verify(now, nxt.path)
    assert rep.safe
    # transition 1 at the start's level, every later one at the scenario's own chi2
    levels = np.full((nxt.path.K, len(sc.hazards)), sc.chi2)
    levels[0] = now.chi2_start
    assert bn.verify(now, nxt.path, levels=levels).safe
    assert not bn.verify(now, nxt.path, levels=sc.chi2).safe       # the relief was needed
    # dense sampling of transition 2 at chi2 (the plan is back at the nominal level after one step)
    x1, x2, P1 = nxt.path.x[1], nxt.path.x[2], nxt.path.P[1]
    d2 = min(_sampled_d2(x1 + s * (x2 - x1), P1 + s * sc.W, h) for s in np.linspace(0, 1, 101) for h in sc.obstacles)
    assert d2 >= sc.chi2 * (1 - 1e-6)


def test_the_relief_moves_exactly_transition_1s_rows_and_not_the_cache_key(case):
    sc, res, x, P, _ = case
    now = bn.relaxed_start(sc, x, P, previous=res, advance=1)
    plain = sc.with_options(x0=res.path.x[1], P0=res.path.P[1])
    model = BeliefModel(now, 19, 0.1)
    D = model.data
    assert D.relief == pytest.approx(sc.chi2 - now.chi2_start) and D.relief > 0
    # a start datum like x0: the compiled forms are the plain scenario's
    assert problem_key(D, 2e-7, "CLARABEL") == problem_key(BeliefModel(plain, 19, 0.1).data, 2e-7, "CLARABEL")
    ws = bn.warm_start(now, bn.reanchor(now, res, 1), sensing="path")
    point = model.tighten(model.from_path(ws.path, ws.lam))
    nlp = build_nlp(model)
    z = nlp.pack(point)
    relaxed, _ = nlp.margin_values(z)
    no_relief = start_values(D).copy()
    no_relief[-1] = 0.0                                 # the start block ends with the relief
    base = np.asarray(nlp.margins(z, no_relief)[0], float).ravel()
    J = len(sc.hazards)
    np.testing.assert_array_equal(relaxed[2 * J:], base[2 * J:])                 # transitions 2.. untouched
    np.testing.assert_allclose(relaxed[:2 * J] - base[:2 * J], D.relief, rtol=0, atol=1e-9)
    # the model's own evaluation (the exact check's) reads the same rows, relief included
    start, end = model.transition_margins(point)
    np.testing.assert_allclose(np.ravel([start[0], end[0]], order="F"), relaxed[:2 * J], atol=1e-8)
    # the frozen prefix (a resumed re-plan) holds the same rows by their bounds
    view = frozen(build_nlp(BeliefModel(sc, 20, 0.1)), model, 1)
    shift = view.source_g(view.lbg)[:2 * J] - nlp.lbg[:2 * J]
    np.testing.assert_allclose(shift, -D.relief, rtol=0, atol=1e-12)


def test_a_resumed_relaxed_replan_is_the_built_horizons_answer(case):
    """ipopt resumed on the last answer's graph (transition 1's bounds
    relieved) and ipopt on the shorter horizon built for the relaxed start
    (a BeliefPath carries no resume state) reach the same optimum."""
    sc, res, x, P, _ = case
    now = bn.relaxed_start(sc, x, P, previous=res, advance=1)
    resumed = bn.replan(now, res, advance=1, method="ipopt")
    built = bn.replan(now, res.path, advance=1, method="ipopt")
    assert resumed.stats["resumed"] == "yes" and built.stats["resumed"] == "no"
    assert resumed.success and built.success
    assert resumed.cost == pytest.approx(built.cost, rel=1e-6)
    assert bn.verify(now, resumed.path).safe and bn.verify(now, built.path).safe


def test_a_relaxed_ccp_replan_takes_the_relief_on_the_longer_step(case):
    """ccp after an executed step, from a start only its relief clears: the
    longer horizon's conic step, frozen, carries the relief at the
    transition after the prefix, and reaches the answer of the step built
    for the shorter horizon; both verified at the levels the scenario states."""
    sc, res, x, P, _ = case
    prev = bn.smooth(sc, res.path, method="ccp")
    now = bn.relaxed_start(sc, x, P, previous=prev, advance=1)
    with pytest.raises(bn.ValidationError):              # at the scenario's level the start is not clear
        now.with_options(start_confidence=None)
    frozen_run = bn.replan(now, prev, advance=1, method="ccp")
    built = bn.replan(now, prev.path, advance=1, method="ccp")
    assert frozen_run.stats["frozen"] == 1 and built.stats["frozen"] == 0
    assert frozen_run.success and built.success
    assert frozen_run.cost == pytest.approx(built.cost, rel=1e-6)
    assert bn.verify(now, frozen_run.path).safe and bn.verify(now, built.path).safe


@pytest.mark.parametrize("changes, field, text", [
    ({"start_confidence": 0.95}, "start.confidence", "above the scenario's own level"),
    ({"start_confidence": 1.0}, "start.confidence", "strictly between 0 and 1"),
    ({"start_confidence": float("nan")}, "start.confidence", "strictly between 0 and 1"),
    ({"start_confidence": 0.5, "risk": 0.05}, "start.confidence", "risk budget"),
])
def test_bad_start_confidence_is_our_error(changes, field, text):
    sc = bn.load_scenario("paper-multi")
    with pytest.raises(bn.ValidationError, match=text) as err:
        sc.with_options(**changes)
    assert err.value.field == field


def test_a_start_not_clear_even_at_its_own_level_names_it(case):
    sc, _, x, P, _ = case
    with pytest.raises(bn.ValidationError, match="at start_confidence 0.85 is not clear"):
        sc.with_options(x0=x, P0=P, start_confidence=0.85)        # chi2 quantile 0.82 chi2 > its 0.7 chi2


def test_the_file_form_keeps_the_start_level(case):
    sc, _, x, P, _ = case
    now = bn.relaxed_start(sc, x, P)
    data = now.to_dict()
    assert data["start"]["confidence"] == now.start_confidence
    assert bn.scenario_from_dict(data) == now
    data["start"]["confidence"] = "high"
    with pytest.raises(ScenarioFileError, match="start.confidence"):
        bn.scenario_from_dict(data)


def test_relaxed_start_refuses_what_no_level_clears(case):
    sc, res, _, P, j = case
    with pytest.raises(bn.ValidationError, match="inside"):
        bn.relaxed_start(sc, sc.hazards[j].vertices.mean(axis=0), P)
    with pytest.raises(bn.ValidationError, match="margin"):
        bn.relaxed_start(sc, res.path.x[1], P, margin=1.0)
    with pytest.raises(bn.ValidationError, match="advance"):
        bn.relaxed_start(sc, res.path.x[1], P, previous=res, advance=20)


def test_a_budget_with_a_relaxed_start_is_refused(case):
    sc, res, x, P, _ = case
    now = bn.relaxed_start(sc, x, P, previous=res, advance=1)
    with pytest.raises(bn.ValidationError, match="start.confidence"):
        bn.replan(now, res, advance=1, risk=0.05)


def test_the_planner_refuses_a_start_only_its_relief_clears(case):
    sc, res, x, P, _ = case
    now = bn.relaxed_start(sc, x, P)
    with pytest.raises(bn.ValidationError, match="re-plan from a previous path") as err:
        bn.plan(now, n_nodes=50)
    assert err.value.field == "start.confidence"
    # a start clear at the scenario's level plans as before, whatever start_confidence says
    assert bn.plan(sc.with_options(start_confidence=0.5), n_nodes=300, seed=0, noise="per_step").success


@pytest.fixture(scope="module", params=["paper-multi", "boxes3d:31"])
def planned(request):
    """(scenario, auto's K = 20 answer) in 2-D and 3-D."""
    if ":" in request.param:
        from belief_nlp.families import generate

        fam, m = request.param.split(":")
        sc = generate(fam, int(m))
    else:
        sc = bn.load_scenario(request.param)
    plan = bn.plan(sc, n_nodes=500, seed=0, noise="per_step")
    return sc, bn.smooth(sc, plan.path, K=20, alpha=0.1)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(step=st.integers(1, 15), direction=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
       sigmas=st.floats(0, 3), shrink=st.floats(0.3, 1.5))
def test_any_estimate_near_the_plan_gets_a_level_its_warm_start_meets(planned, step, direction, sigmas, shrink):
    """Property: wherever the estimate lands near the plan (up to 3 standard
    deviations off, its covariance scaled), relaxed_start either refuses a
    mean inside a hazard or gives a scenario whose re-anchored warm start is
    built and verified at the levels the scenario states (2-D and 3-D)."""
    sc, res = planned
    u = np.asarray(direction[:sc.dim])
    if not np.linalg.norm(u) > 1e-6:
        return
    P = shrink * res.path.P[step]
    x = res.path.x[step] + sigmas * np.sqrt(np.diag(res.path.P[step])) * u / np.linalg.norm(u)
    try:
        now = bn.relaxed_start(sc, x, P, previous=res, advance=step)
    except bn.ValidationError as exc:
        assert exc.field == "x0" and "inside" in str(exc)
        return
    assert now.chi2_start <= sc.chi2
    ws = bn.warm_start(now, bn.reanchor(now, res, step), sensing="path")
    assert ws.report.safe and bn.verify(now, ws.path).safe
