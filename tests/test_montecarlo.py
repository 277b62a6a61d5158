"""Monte-Carlo safety (belief_nlp.study.montecarlo) against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

import belief_nlp as bn
from belief_nlp.study.montecarlo import clopper_pearson, simulate


def _strip_scenario(sigma2: float, domain=((0.0, 0.0), (1.0, 1.0)), target=((0.8, 0.0), (1.0, 1.0)),
                    obstacles=()) -> bn.Scenario:
    return bn.scenario_from_dict({
        "name": "strip", "confidence": 0.9, "alpha": 0.1,
        "start": {"x": [0.1, 0.5], "P": [[1e-14, 0.0], [0.0, 1e-14]]},
        "noise": {"W": [[1e-12, 0.0], [0.0, sigma2]], "W_rate": 1e-3},
        "domain": {"box": {"lower": list(domain[0]), "upper": list(domain[1])}},
        "target": {"box": {"lower": list(target[0]), "upper": list(target[1])}},
        "obstacles": [dict(o) for o in obstacles]})


def _two_sided_exit(h: float, sigma: float) -> float:
    """P(sup_{s<=1} |B_s| >= h) for a Brownian motion of variance sigma^2 per unit time (series)."""
    stay = sum((-1) ** k / (2 * k + 1) * math.exp(-((2 * k + 1) ** 2) * math.pi ** 2 * sigma ** 2 / (8 * h ** 2))
               for k in range(50))
    return 1.0 - 4.0 / math.pi * stay


def test_clopper_pearson_known_values():
    lo, hi = clopper_pearson(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.3085, abs=1e-4)       # 1 - 0.025**(1/10)
    lo, hi = clopper_pearson(10, 10)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** 0.1, abs=1e-9)
    lo, hi = clopper_pearson(50, 100)
    assert lo < 0.5 < hi and hi - lo == pytest.approx(0.2034, abs=2e-3)



@pytest.mark.parametrize("k,n,level", [(0, 7, 0.95), (3, 40, 0.95), (17, 20, 0.99), (412, 10_000, 0.9)])
def test_clopper_pearson_matches_scipy_binomtest(k, n, level):
    """Our interval (beta quantiles) equals scipy's exact binomial interval."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
    assert clopper_pearson(k, n, level) == pytest.approx((ci.low, ci.high), abs=1e-10)

def test_straight_transition_between_walls_matches_brownian_exit_probability():
    # one transition along y = 0.5, walls at distance h = 0.5 above and below: a run fails
    # when the lateral Brownian motion leaves (-h, h) -- a classical series, independent
    # of the simulator. Discrete monitoring (n samples) sees the barrier ~0.5826 sigma/sqrt(n)
    # further away (Broadie-Glasserman-Kou), which the reference includes.
    sigma2 = 0.04
    sc = _strip_scenario(sigma2)
    x = np.array([[0.1, 0.5], [0.9, 0.5]])
    path = bn.BeliefPath.from_sensing(x, sc.P0, np.zeros((1, 2, 2)), W=sc.W)
    n, runs = 200, 40_000
    mc = simulate(sc, path, runs=runs, substeps=n, seed=3)
    sigma = math.sqrt(sigma2)
    expected = _two_sided_exit(0.5 + 0.5826 * sigma / math.sqrt(n), sigma)
    lo, hi = clopper_pearson(mc.failures, runs, 0.999)
    assert lo <= expected <= hi, (mc.summary(), expected)
    # a run that ends beyond a wall also ends outside the target: misses are a subset of exits
    assert mc.collisions == 0 and mc.exits == mc.failures and mc.misses <= mc.exits
    assert mc.nominal_rate == pytest.approx(0.1)


def test_end_distribution_realises_the_planned_prior_covariance():
    # No obstacles, walls far away, a tight target: a run fails only by ending outside the
    # target. With the estimate-corrected control the end deviation is N(0, P_prior_K)
    # exactly (the Kalman filter realising S_k), so the miss probability is a product of
    # normal probabilities per axis (diagonal W and S keep everything diagonal).
    sc = bn.scenario_from_dict({
        "name": "end", "confidence": 0.9, "alpha": 0.1,
        "start": {"x": [0.0, 0.0], "P": [[1e-4, 0.0], [0.0, 4e-4]]},
        "noise": {"W": [[2e-4, 0.0], [0.0, 1e-4]], "W_rate": 1e-3},
        "domain": {"box": {"lower": [-10.0, -10.0], "upper": [10.0, 10.0]}},
        "target": {"box": {"lower": [0.27, -0.03], "upper": [0.33, 0.03]}}, "obstacles": []})
    x = np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0], [0.3, 0.0]])
    S = np.array([np.diag([1e4, 0.0]), np.diag([0.0, 3e3]), np.diag([5e3, 5e3])])
    path = bn.BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)
    var = np.diag(path.P_prior[-1])
    half = 0.03
    inside = np.prod([2 * norm.cdf(half / math.sqrt(v)) - 1 for v in var])
    runs = 40_000
    mc = simulate(sc, path, runs=runs, substeps=4, seed=11)
    lo, hi = clopper_pearson(mc.failures, runs, 0.999)
    assert lo <= 1 - inside <= hi, (mc.summary(), 1 - inside)
    # open loop ignores the measurements: the deviation is the summed noise, P0 + K W
    var_ol = np.diag(path.P[0] + 3 * sc.W)
    inside_ol = np.prod([2 * norm.cdf(half / math.sqrt(v)) - 1 for v in var_ol])
    mc_ol = simulate(sc, path, runs=runs, substeps=4, seed=11, control="open_loop")
    lo, hi = clopper_pearson(mc_ol.failures, runs, 0.999)
    assert lo <= 1 - inside_ol <= hi, (mc_ol.summary(), 1 - inside_ol)


def test_obstacle_hits_counted_and_reproducible():
    # a box obstacle across the straight line: every run must hit it
    sc = _strip_scenario(1e-6, obstacles=[{"name": "block", "box": {"lower": [0.45, 0.3], "upper": [0.55, 0.7]}}])
    x = np.array([[0.1, 0.5], [0.5, 0.5], [0.9, 0.5]])
    path = bn.BeliefPath.from_sensing(x, sc.P0, np.zeros((2, 2, 2)), W=sc.W)
    mc = simulate(sc, path, runs=500, substeps=10, seed=0)
    assert mc.collisions == 500 and mc.rate == 1.0
    a = simulate("paper-multi", _paper_path(), runs=300, seed=5)
    b = simulate("paper-multi", _paper_path(), runs=300, seed=5)
    assert a == b


def _paper_path() -> bn.BeliefPath:
    sc = bn.load_scenario("paper-multi")
    wp = np.array([(0.15, 0.50), (0.15, 0.80), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)])
    x = np.vstack([wp[:1]] + [wp[i] + np.linspace(0.25, 1, 4)[:, None] * (wp[i + 1] - wp[i]) for i in range(5)])
    return bn.BeliefPath.from_sensing(x, sc.P0, np.broadcast_to(1e4 * np.eye(2), (len(x) - 1, 2, 2)), W=sc.W)


def test_bad_arguments_raise():
    p = _paper_path()
    with pytest.raises(bn.ValidationError, match="runs"):
        simulate("paper-multi", p, runs=0)
    with pytest.raises(bn.ValidationError, match="control"):
        simulate("paper-multi", p, control="pid")
    with pytest.raises(bn.ValidationError, match="path"):
        simulate("paper-multi", "not a path")
