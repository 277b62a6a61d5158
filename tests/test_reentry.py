"""Switched-off sensing back on after the polish (methods/nlp_reentry.py)."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
import belief_nlp.methods.nlp_engine as engine
from belief_nlp.methods import nlp_reentry, nlp_stationary
from conftest import switching_off_more


def _warm(sc, K, seed=0):
    return bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=seed, noise="per_step").path, K=K)


@pytest.fixture(scope="module")
def pm():
    return bn.load_scenario("paper-multi")


def _lagrangian(nlp, p, lam_g):
    def lag(zv):
        f, g = nlp.fg(zv, p)
        return float(f) + float(np.dot(np.asarray(g).ravel(), lam_g))
    return lag


def test_each_descent_column_lowers_the_lagrangian_as_its_eigenvalue_says(pm, monkeypatch):
    """At a polished answer with a negative block (the polish switching off up
    to 5x the floor, without rounds), putting s v into the switched-off
    column changes the Lagrangian (function values alone) by s^2 w / 2,
    w < 0: each direction the rounds may take lowers it."""
    seen = []

    def spy(*args):
        seen.append(args)
        return nlp_stationary.sensing_stationary(*args)

    monkeypatch.setattr(engine, "sensing_stationary", spy)
    switching_off_more(monkeypatch)
    res = bn.smooth(pm, _warm(pm, 20), alpha=1.0, method="ipopt", reenter=0)
    assert res.stats["sensing_stationary"] is False and res.stats["sensing_reentered"] == 0
    nlp, solver, p, z, lam_g = seen[-1]
    cols = nlp_stationary.descent_columns(nlp, solver, p, z, lam_g)
    assert cols and all(w < 0 for *_, w in cols)
    lag, s = _lagrangian(nlp, p, lam_g), 1e-4
    base = lag(z)
    for _, idx, v, w in cols:
        assert np.allclose(z[idx], 0.0)                     # switched off
        moved = z.copy()
        moved[idx] = s * v
        assert (lag(moved) - base) / (0.5 * s ** 2) == pytest.approx(w, rel=1e-3, abs=1e-6)


def test_a_round_lowers_a_non_stationary_answer_to_what_the_ccp_polish_finds(pm, monkeypatch):
    """The same answer, every negative column counted as worth it (BENEFIT
    0): the rounds end lower than the polish alone, exactly safe (verify),
    and as low as auto's CCP polish from the polish's answer (a second
    method, to 1e-6)."""
    switching_off_more(monkeypatch)
    ws = _warm(pm, 20)
    alone = bn.smooth(pm, ws, alpha=1.0, method="ipopt", reenter=0)
    ccp = bn.smooth(pm, ws, alpha=1.0, ipopt_options={"reenter": 0})
    assert ccp.method == "auto:ipopt+ccp"
    monkeypatch.setattr(nlp_reentry, "BENEFIT", 0.0)
    res = bn.smooth(pm, ws, alpha=1.0, method="ipopt")
    assert res.stats["sensing_reentered"] >= 1
    assert res.cost < alone.cost * (1 - 1e-6)
    assert res.cost <= ccp.cost * (1 + 1e-6)
    assert res.success and bn.verify(pm, res.path).safe
    assert len(res.stats["attempts"]) > len(alone.stats["attempts"])


def test_sensing_that_pays_comes_back_on_by_default_and_auto_skips_its_ccp_polish(pm):
    """paper-multi, planner seed 6, K = 40, alpha = 1: the polish's answer
    would sense again at the end of an unsensed stretch (its block's
    eigenvalue -107, 3.6 x the sensing's price, measured). One round
    lowers the cost by more than 0.1 % to a stationary answer, below auto's
    CCP polish of the polish's answer, and auto then skips that polish."""
    ws = _warm(pm, 40, seed=6)
    alone = bn.smooth(pm, ws, alpha=1.0, method="ipopt", reenter=0, step_down=0)      # (the step-down would too)
    assert alone.stats["sensing_stationary"] is False
    res = bn.smooth(pm, ws, alpha=1.0, method="ipopt")
    assert res.stats["sensing_reentered"] >= 1 and res.stats["sensing_stationary"] is True
    assert res.cost < alone.cost * (1 - 1e-3) and bn.verify(pm, res.path).safe
    ccp = bn.smooth(pm, ws, alpha=1.0, ipopt_options={"reenter": 0, "step_down": 0})
    assert ccp.method == "auto:ipopt+ccp" and res.cost <= ccp.cost * (1 + 1e-6)
    auto = bn.smooth(pm, ws, alpha=1.0)
    assert auto.method == "auto:ipopt" and auto.cost == pytest.approx(res.cost, rel=1e-9)


def test_the_option_is_checked_and_zero_turns_the_rounds_off(pm):
    ws = _warm(pm, 10)
    with pytest.raises(bn.errors.ValidationError, match="reenter"):
        bn.smooth(pm, ws, alpha=1.0, method="ipopt", reenter=-1)
    res = bn.smooth(pm, ws, alpha=1.0, method="ipopt", reenter=0)
    assert res.stats["sensing_reentered"] == 0
