"""Issue 20, item 5: an MPC runs with the smoother's risk allocation.

The stage bundle takes each hazard's level as a run-time parameter, one
column per stage (Opti); a closed loop over the smoothed path with its
allocation keeps every applied transition clear at its own level, so the
closed-loop path's certified step-time bound -- recomputed here by
:func:`belief_nlp.risk.path_risk` and :func:`belief_nlp.verify` -- stays
within the budget."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.export.bundle import stage_bundle
from belief_nlp.export.closed_loop import closed_loop
from belief_nlp.risk import path_risk

BUDGET = 0.3


@pytest.fixture(scope="module")
def smoothed():
    sc = bn.load_scenario("paper-multi")
    plan = bn.plan(sc, n_nodes=300, seed=0, noise="per_step")
    return sc, bn.smooth(sc, plan.path, method="ipopt", K=12, alpha=0.1, risk=BUDGET)


def test_bundle_levels_are_parameters(smoothed):
    sc, r = smoothed
    b = stage_bundle(sc, scaled=True)
    J = len(sc.hazards)
    p = b.params(levels=np.arange(1.0, J + 1))
    assert np.array_equal(p[-J:], np.arange(1.0, J + 1)) and np.array_equal(p[:-J], b.params()[:-J])
    cols = b.stage_params(r.risk.levels)
    assert cols.shape == (b.params().size, r.path.K) and np.array_equal(cols[-J:], r.risk.levels.T)
    # one hazard's level moves only that hazard's two margin rows, by exactly the change
    x0, x1 = np.array([0.1, 0.1]) / b.sigma, np.array([0.12, 0.1]) / b.sigma
    P, W = np.eye(2) * 1e-4 / b.sigma**2, sc.W / b.sigma**2
    lam = np.full(b.n_lam, 0.1)
    g0 = np.asarray(b(x0, P, x1, W, lam, p=b.params())).ravel()
    lv = np.full(J, sc.chi2)
    lv[2] += 1.5
    g1 = np.asarray(b(x0, P, x1, W, lam, p=b.params(levels=lv))).ravel()
    diff = g0 - g1
    assert np.allclose(diff[4:6], 1.5) and np.allclose(np.delete(diff, [4, 5]), 0.0)
    with pytest.raises(ValidationError, match="levels"):
        b.params(levels=np.ones(J + 1))
    with pytest.raises(ValidationError, match="levels"):
        b.stage_params(np.ones(J))


@pytest.mark.parametrize("tool", ["opti", "dompc", "rockit"])
def test_closed_loop_with_the_allocation_stays_within_the_budget(smoothed, tool):
    sc, r = smoothed
    cl = closed_loop(sc, tool, horizon=5, steps=r.path.K, reference=r.path, levels=r.risk.levels)
    assert cl.K == r.path.K
    assert path_risk(sc, cl).step_time <= BUDGET
    rep = bn.verify(sc, cl, levels=r.risk.levels, budget=BUDGET)
    assert rep.safe, rep.problems


def test_closed_loop_levels_are_checked(smoothed):
    sc, r = smoothed
    with pytest.raises(ValidationError, match="levels"):
        closed_loop(sc, "opti", horizon=5, steps=r.path.K, reference=r.path, levels=r.risk.levels[:-1])
    with pytest.raises(ValidationError, match="levels"):
        closed_loop(sc, "opti", horizon=5, steps=r.path.K, reference=r.path, levels=-r.risk.levels)
