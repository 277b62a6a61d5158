"""The floor stepped down after a polish without an answer (methods/nlp_stepdown.py)."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods import nlp_recorder, nlp_stepdown
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp


def _warm(sc, K, seed=0):
    return bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=seed, noise="per_step").path, K=K)


@pytest.fixture(scope="module")
def pm():
    return bn.load_scenario("paper-multi")


def test_a_polish_without_an_answer_steps_the_floor_down_below_the_ccp_polish(pm):
    """paper-multi, planner seed 8, K = 40, alpha = 1: switching the floor's
    sensing off leaves the polish without an answer (measured: its cap of
    50), so the answer pays for the floor. Stepped down to floor / 10, the
    answer is more than 0.2 % lower, exactly safe (verify), stationary in S,
    and not above auto's CCP polish of the floored answer (a second method);
    auto then skips that polish."""
    ws = _warm(pm, 40, seed=8)
    alone = bn.smooth(pm, ws, alpha=1.0, method="ipopt", step_down=0)
    assert alone.stats["floor_stepped_down"] is None and alone.stats["sensing_stationary"] is None
    res = bn.smooth(pm, ws, alpha=1.0, method="ipopt")
    assert res.stats["floor_stepped_down"] == "polished" and res.stats["sensing_stationary"] is True
    assert res.success and bn.verify(pm, res.path).safe
    assert res.cost < alone.cost * (1 - 2e-3)
    assert len(res.stats["attempts"]) > len(alone.stats["attempts"])
    ccp = bn.smooth(pm, ws, alpha=1.0, ipopt_options={"step_down": 0})
    assert ccp.method == "auto:ipopt+ccp" and res.cost <= ccp.cost * (1 + 1e-6)
    auto = bn.smooth(pm, ws, alpha=1.0)
    assert auto.method == "auto:ipopt" and auto.cost == pytest.approx(res.cost, rel=1e-9)


def test_sensing_that_would_pay_after_the_rounds_steps_the_floor_down():
    """random-polygons map 0, K = 80, alpha 1: the polish answers, but
    sensing at a switched-off stretch would pay (shares 0.47-0.56 of its
    price at steps 72-76) and the re-entry round runs to its cap (measured).
    Stepped down, the answer is stationary in S, more than 0.3 % lower,
    exactly safe, and not above auto's CCP polish of the unstepped answer (a
    second method); auto then skips that polish."""
    from belief_nlp.families import generate

    sc = generate("random-polygons", 0)
    ws = _warm(sc, 80)
    alone = bn.smooth(sc, ws, alpha=1.0, method="ipopt", step_down=0)
    assert alone.stats["polish_status"] == "Solve_Succeeded" and alone.stats["sensing_stationary"] is False
    res = bn.smooth(sc, ws, alpha=1.0, method="ipopt")
    assert res.stats["floor_stepped_down"] == "polished" and res.stats["sensing_stationary"] is True
    assert res.success and bn.verify(sc, res.path).safe and res.cost < alone.cost * (1 - 3e-3)
    ccp = bn.smooth(sc, ws, alpha=1.0, ipopt_options={"step_down": 0})
    assert ccp.method == "auto:ipopt+ccp" and res.cost <= ccp.cost * (1 + 1e-6)
    auto = bn.smooth(sc, ws, alpha=1.0)
    assert auto.method == "auto:ipopt" and auto.cost == pytest.approx(res.cost, rel=1e-9)


def test_a_polish_far_from_feasible_at_its_probe_ends_there_and_steps_down(monkeypatch):
    """random-polygons map 2, K = 80, alpha 0.1: the polish's iterate PROBE
    still violates the rows by more than PROBE_VIOLATION, so it ends there
    and the step-down follows. Left to run (the probe pushed out of reach),
    the same polish reaches its cap of 50 without an answer, and the
    step-down then gives the same answer in 29 more iterations. Without a
    step-down to follow, nothing is probed."""
    from belief_nlp.families import generate

    sc = generate("random-polygons", 2)
    ws = _warm(sc, 80)
    res = bn.smooth(sc, ws, alpha=0.1, method="ipopt")
    first, polish = res.stats["attempts"][:2]
    assert polish["return_status"] == "Far_From_Feasible" and polish["iter_count"] == nlp_recorder.PROBE
    # the probed iterate, as the history recorded it: a Kalman row or a margin beyond the level
    rec = [h for h in res.history if h.iteration == first["iter_count"] + nlp_recorder.PROBE][-1]
    assert max(rec.kalman_gap, -rec.min_margin) > nlp_recorder.PROBE_VIOLATION
    assert res.stats["floor_stepped_down"] == "polished" and res.success and bn.verify(sc, res.path).safe
    alone = bn.smooth(sc, ws, alpha=0.1, method="ipopt", step_down=0)
    assert alone.stats["attempts"][1]["return_status"] == "Maximum_Iterations_Exceeded"
    monkeypatch.setattr(nlp_recorder, "PROBE", 10 ** 9)
    full = bn.smooth(sc, ws, alpha=0.1, method="ipopt")
    assert full.stats["attempts"][1]["return_status"] == "Maximum_Iterations_Exceeded"
    assert full.stats["floor_stepped_down"] == "polished" and res.cost == pytest.approx(full.cost, rel=1e-6)
    assert res.stats["iter_count"] <= full.stats["iter_count"] - 25


def test_released_multipliers_are_those_of_the_floor_bounds(small_start):
    """``released`` zeroes exactly the lower-bound multipliers (negative in
    CasADi's lam_x) of the entries the floor bounds, found independently as
    the "logchol" bounds at log(floor), and leaves every other one as it was."""
    sc, ws = small_start
    nlp = build_nlp(BeliefModel(sc, ws.K, 1.0), "logchol", floor=3e-2)
    floored = np.flatnonzero(np.isclose(nlp.lbz, np.log(3e-2)))
    assert floored.size == ws.K * sc.dim
    lam = np.random.default_rng(0).normal(size=nlp.lbz.size)
    out = nlp_stepdown.released(nlp, lam)
    others = np.setdiff1d(np.arange(lam.size), floored)
    assert np.array_equal(out[others], lam[others])
    assert np.array_equal(out[floored], np.maximum(lam[floored], 0.0)) and (lam[floored] < 0).any()


def test_the_option_is_checked_and_a_polish_with_an_answer_runs_none(pm):
    ws = _warm(pm, 10)
    for bad in (1, 1.5, -0.1, "x", True):
        with pytest.raises(bn.errors.ValidationError, match="step_down"):
            bn.smooth(pm, ws, alpha=1.0, method="ipopt", step_down=bad)
    res = bn.smooth(pm, ws, alpha=1.0, method="ipopt")
    assert res.stats["polish_status"] == "Solve_Succeeded" and res.stats["floor_stepped_down"] is None
