"""Certified end-to-end collision-probability bounds (belief_nlp.risk).

Each bound is held to an independent computation: the Gaussian tail to
scipy's normal law, the first-passage formula to the zero-drift reflection
principle and to a Brownian-bridge Monte-Carlo, the per-pair clearances to
verify's sampled margins, and the path totals to the study engine's
closed-loop simulator.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

import belief_nlp as bn
from belief_nlp.risk import crossing_probability, gaussian_tail, path_risk
from belief_nlp.study.montecarlo import clopper_pearson, simulate


def test_gaussian_tail_is_the_normal_tail_beyond_a_hyperplane():
    m = np.array([1e-12, 1.0, 4.605170185988092, 9.1, 25.0])
    np.testing.assert_allclose(gaussian_tail(m), norm.sf(np.sqrt(m)), rtol=1e-12)
    assert gaussian_tail(4.605170185988092) == pytest.approx(0.0159, abs=1e-4)     # the paper's 90 % ellipse
    assert gaussian_tail(-1.0) == 1.0 and gaussian_tail(0.0) == 1.0       # no clearance proven: no claim


def test_crossing_without_drift_is_twice_the_tail():
    """Reflection principle: P(min B <= -h) = 2 Phi(-h / sigma) for a fixed start."""
    h = np.array([0.3, 1.0, 2.5])
    got = crossing_probability(h, 0.0, 0.0, 1.0, 0.0)
    np.testing.assert_allclose(got, 2 * norm.cdf(-h), rtol=1e-10)


def test_crossing_with_drift_and_random_start_matches_a_bridge_monte_carlo():
    """Brownian motion with drift from a Gaussian start (and the feedback
    offset D): crossings counted exactly per interval by the Brownian-bridge
    probability exp(-2 a b / (sigma^2 dt)), an independent estimate."""
    rng = np.random.default_rng(0)
    m0, v0, mu, s2, e, vd = 2.0, 0.3, -1.2, 0.8, 0.0, 0.2
    n, steps = 200_000, 50
    E = rng.normal(0, np.sqrt(v0), n)
    D = rng.normal(0, np.sqrt(vd), n)
    y = m0 + E + D
    hit = y <= e
    dt = 1.0 / steps
    for _ in range(steps):
        y_next = y + (mu - D) * dt + rng.normal(0, np.sqrt(s2 * dt), n)
        a, b = y - e, y_next - e
        p_bridge = np.where((a > 0) & (b > 0), np.exp(-2 * a * b / (s2 * dt)), 1.0)
        hit |= rng.random(n) < p_bridge
        y = y_next
    p_mc = hit.mean()
    se = np.sqrt(p_mc * (1 - p_mc) / n)
    bound = float(crossing_probability(m0, v0, mu, s2, e, vd))
    assert p_mc - 4 * se <= bound <= 1.01 * p_mc + 4 * se         # an upper Riemann sum: above, and tight


@pytest.fixture(scope="module")
def smoothed():
    sc = bn.load_scenario("paper-multi")
    planned = bn.plan(sc, n_nodes=300, seed=0, noise="per_step")
    res = bn.smooth(sc, planned, K=10, alpha=1.0)
    assert res.safe
    return sc, res


def test_pair_bounds_come_from_certified_clearances(smoothed):
    """The clearance is a lower bound on verify's sampled minimum (an upper
    bound on the true one) and tight to it; step_time is their tails' Boole sum."""
    sc, res = smoothed
    rb = path_risk(sc, res.path, res.certificates)
    sampled = bn.verify(sc, res.path).transition_margins + sc.chi2
    assert np.all(rb.clearance <= sampled + 1e-9 * (1 + sampled))
    np.testing.assert_allclose(rb.clearance, sampled, rtol=1e-4)
    assert rb.step_time == pytest.approx(min(1.0, norm.sf(np.sqrt(rb.clearance)).sum()), rel=1e-9)
    # independent arithmetic on the sampled margins gives (almost) the same end-to-end number
    assert rb.step_time == pytest.approx(norm.sf(np.sqrt(sampled)).sum(), rel=1e-3)
    assert np.all(rb.continuous_pairs >= rb.pairs - 1e-12)      # touching at some instant >= being there at one
    assert rb.pairs.shape == (res.path.K, len(sc.hazards)) and 0 < rb.step_time <= rb.continuous <= 1


def test_verify_reports_the_bound(smoothed):
    sc, res = smoothed
    rep = bn.verify(sc, res.path, certificates=res.certificates)
    assert rep.risk is not None and rep.risk_bound == rep.risk.step_time
    assert "collision risk <=" in rep.summary()
    d = rep.to_dict()
    assert d["risk_step_time"] == pytest.approx(rep.risk_bound) and rep.risk.continuous >= d["risk_step_time"]
    assert "collision probability <=" in res.summary()
    assert "not bounded" in rep.risk.statement


def test_monte_carlo_rates_stay_within_the_certified_bounds(smoothed):
    """The closed-loop simulator (feedback on the Kalman estimate, Brownian
    noise between steps): the rate of runs inside a hazard at a step time is
    within the step-time bound, and the rate along finely sampled
    trajectories within the continuous-time bound (95 % Clopper-Pearson
    lower ends below the bounds)."""
    sc, res = smoothed
    rb = bn.verify(sc, res.path).risk
    mc = simulate(sc, res.path, runs=6000, substeps=60, seed=3)
    lo_step, _ = clopper_pearson(mc.step_hazard_runs, mc.runs)
    lo_cont, _ = clopper_pearson(mc.hazard_runs, mc.runs)
    assert lo_step <= rb.step_time and lo_cont <= rb.continuous
    assert mc.step_hazard_runs <= mc.hazard_runs
