"""Risk allocation (issue 20, items 2-3): an end-to-end collision budget with
per-pair levels as decision variables of the one model.

Every bound asserted here is recomputed independently of the smoother, from
the returned path: :func:`belief_nlp.risk.path_risk` (exact transition
minimiser plus the result's certificates) and :func:`belief_nlp.verify`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

import belief_nlp as bn
from belief_nlp.allocation import RiskAllocation, RiskBudget, level_bounds, level_for, tail
from belief_nlp.errors import InfeasibleStartError, ValidationError
from belief_nlp.model import BeliefModel
from belief_nlp.model.cvxpy_form import compile_problem
from belief_nlp.model.doc_budget import _level_functions, level_curvature_bound
from belief_nlp.risk import path_risk
from belief_nlp.smoother.warmstart import warm_start

K = 12
BUDGET = 0.3


@pytest.fixture(scope="module")
def setting():
    sc = bn.load_scenario("paper-multi")
    plan = bn.plan(sc, n_nodes=300, seed=0, noise="per_step")
    assert plan.success
    return sc, plan.path


@pytest.fixture(scope="module")
def results(setting):
    sc, path = setting
    out = {"fixed": bn.smooth(sc, path, method="ipopt", K=K, alpha=0.1)}
    for m in ("ipopt", "ccp"):
        out[m] = bn.smooth(sc, path, method=m, K=K, alpha=0.1, risk=BUDGET)
    return out


# ------------------------------------------------------------------ the tail
def test_tail_is_the_gaussian_tail_and_level_for_inverts_it():
    tau = np.array([0.5, 4.605, 9.1, 25.0])
    assert np.allclose(tail(tau), norm.sf(np.sqrt(tau)), rtol=1e-12)
    assert np.allclose(level_for(tail(tau)), tau, rtol=1e-9)
    assert tail(0.0) == 1.0 and tail(-1.0) == 1.0


def test_level_majorant_bounds_the_level_and_is_tight_at_the_point():
    """tau = h(l) (the level of log risk l) lies below tau~ + h'(l~) dl +
    M_up/2 max(dl, 0)^2 + h''(l~)/2 max(-dl, 0)^2 on the whole budgeted range,
    with h' and h'' from CasADi checked against finite differences. (CasADi's
    g is 1 - erf: ~1e-16 absolute, so points beyond tau ~ 35 lose digits; the
    levels stop at tau_hi.)"""
    budget = 0.05
    f = _level_functions()
    m_up = level_curvature_bound(budget)
    ells = np.linspace(np.log(1e-12), np.log(budget), 20001)
    h = level_for(np.exp(ells))
    for tau_t in (2.8, 4.6, 9.0, 20.0, 28.0):      # tau_hi of this budget: 25.3
        lt, h1, h2 = (float(v) for v in f(tau_t))
        assert math.isclose(lt, math.log(tail(tau_t)), rel_tol=1e-8)
        step = 1e-4
        fd = (level_for(np.exp(lt + step)) - level_for(np.exp(lt - step))) / (2 * step)
        fd2 = (level_for(np.exp(lt + step)) - 2 * level_for(np.exp(lt)) + level_for(np.exp(lt - step))) / step**2
        assert math.isclose(h1, fd, rel_tol=1e-5) and math.isclose(h2, fd2, rel_tol=1e-3)
        dl = ells - lt
        bound = tau_t + h1 * dl + 0.5 * m_up * np.maximum(dl, 0) ** 2 + 0.5 * h2 * np.maximum(-dl, 0) ** 2
        assert np.all(bound >= h * (1 - 1e-9))


def test_level_bounds_bracket_the_uniform_level():
    lo, hi = level_bounds(0.05, 200)
    assert math.isclose(tail(lo), 0.05) and math.isclose(tail(hi), 1e-3 * 0.05 / 200, rel_tol=1e-9)
    assert lo < RiskBudget(0.05).uniform_level(200) < hi


@pytest.mark.parametrize("bad", [0, -0.1, 0.5, 1.0, float("nan"), float("inf"), True, "0.1", None])
def test_bad_budgets_get_a_typed_error(bad):
    with pytest.raises(ValidationError, match="risk"):
        RiskBudget(bad)


def test_bad_allocation_and_kind_are_named():
    with pytest.raises(ValidationError, match="allocation"):
        RiskBudget(0.1, allocation="greedy")
    with pytest.raises(ValidationError, match="risk_kind"):
        RiskBudget(0.1, kind="everywhere")


def test_smooth_rejects_bad_budgets_before_any_work(setting):
    sc, path = setting
    for bad in (0.0, 1.2, float("nan")):
        with pytest.raises(ValidationError, match="risk"):
            bn.smooth(sc, path, risk=bad)
    with pytest.raises(ValidationError, match="allocation"):
        bn.smooth(sc, path, allocation="uniform")            # no budget to allocate


# ------------------------------------------------------------------ the model
def test_convex_step_in_budget_mode_is_feasible_at_its_point(setting):
    """The step's point satisfies every cone of its own convexification
    (levels = the point's clearances): the step can never be infeasible."""
    sc, path = setting
    model = BeliefModel(sc, K, 0.1, risk=RiskBudget(BUDGET))
    ws = warm_start(sc, path, K=K, chi2=sc.chi2)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    lo, hi = model.data.level_bounds
    z.tau = np.clip(model.clearances(z) / (1 + 1e-6), lo, hi)
    assert np.sum(tail(z.tau)) <= BUDGET
    step = compile_problem(model.convex_form)
    J = len(sc.hazards)
    step.set_point(z, np.ones((K, J)), np.ones((K, J)))
    step.z.value = step.layout.point_vector(z)
    for name, con in step.constraints.items():
        # (CVXPY measures an exponential cone by projection: its points on the boundary read ~1e-7)
        assert np.max(con.violation(), initial=0.0) <= (1e-6 if name in ("logdet_exp", "budget_exp") else 1e-7), name
    assert {"budget_exp", "budget_steps", "budget_levels", "budget_total"} <= set(step.constraints)


def test_nlp_levels_round_trip(setting):
    from belief_nlp.model.nlp_form import build_nlp

    sc, path = setting
    model = BeliefModel(sc, K, 0.1, risk=RiskBudget(BUDGET))
    ws = warm_start(sc, path, K=K, chi2=sc.chi2)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    z.tau = np.linspace(3.0, 9.0, K * len(sc.hazards)).reshape(K, -1)
    nlp = build_nlp(model)
    back = nlp.unpack(nlp.pack(z))
    assert np.allclose(back.tau, z.tau)
    assert nlp.info["n_budget"] == 1 and nlp.ubg[-1] == 1.0



def test_polish_start_frees_only_the_levels_its_switch_off_breaks(setting):
    """The exact-Cholesky polish switches off the sensing held at the floor.
    Under a budget it holds every level where the first stage put it, except
    those of the pairs whose certified clearance (the model's, recomputed
    here) then falls below their level: only those may re-balance."""
    from belief_nlp.model.nlp_form import build_nlp

    sc, path = setting
    model = BeliefModel(sc, K, 1.0, risk=RiskBudget(BUDGET))
    ws = warm_start(sc, path, K=K, chi2=sc.chi2)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    tau_lo, tau_hi = model.data.level_bounds
    z.tau = np.clip(model.clearances(z) / (1 + 1e-3), tau_lo, tau_hi)      # every pair's rows hold
    nlp = build_nlp(model, "cholesky")
    zv = nlp.pack(z)
    z0, lbz, ubz = nlp.switch_off(zv, nlp.lbz, nlp.ubz, 1e9)             # a floor above all sensing
    assert np.all(z0[nlp.info["sensing_offset"]:][:K * 3] == 0.0)
    after = model.clearances(nlp.unpack(z0))
    n = K * len(sc.hazards)
    lo, hi = lbz[-n:].reshape(K, -1), ubz[-n:].reshape(K, -1)       # levels ordered (k, j) as the rows
    free = lo < hi
    broken = after < z.tau * (1 - 1e-6)
    sure = broken | (after > z.tau * (1 + 1e-5))                     # away from the rows' 1e-6 margin
    assert 0 < broken.sum() < n
    np.testing.assert_array_equal(free[sure], broken[sure])
    assert np.all(lo[free] == tau_lo) and np.all(hi[free] == tau_hi)
    assert np.allclose(lo[~free], z.tau[~free]) and np.allclose(z0[-n:], z.tau.ravel())


def test_continuous_polish_start_frees_the_transitions_after_switched_off_steps(setting):
    """Under a continuous-time budget a pair's rows at transition k + 1 read
    Sigma_{k+1} through Q_k, which the polish moves when step k's sensing is
    switched off: those pairs' levels are free; with nothing switched off
    every level is held."""
    from belief_nlp.model.nlp_form import build_nlp

    sc, path = setting
    model = BeliefModel(sc, K, 1.0, risk=RiskBudget(BUDGET, kind="continuous"))
    ws = warm_start(sc, path, K=K, chi2=sc.chi2)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    z.tau = np.full((K, len(sc.hazards)), model.data.level_bounds[0])
    nlp = build_nlp(model, "cholesky")
    zv = nlp.pack(z)
    n = K * len(sc.hazards)
    _, lo, hi = nlp.switch_off(zv, nlp.lbz, nlp.ubz, 1e9)              # every step's sensing off
    free = (lo[-n:] < hi[-n:]).reshape(K, -1)
    assert free[1:].all()
    _, lo, hi = nlp.switch_off(zv, nlp.lbz, nlp.ubz, 0.0)              # nothing off: every level held
    assert np.all(lo[-n:] == hi[-n:])



@pytest.mark.parametrize("budget", [0.05, BUDGET])
def test_optimal_budget_starts_at_the_lowest_level_that_fits(setting, budget):
    """The warm start under an optimal budget is the ladder's lowest level
    whose certified bound (recomputed by path_risk) is within 97 % of the
    budget: the least sensing that fits. A linear scan of every rung is the
    independent answer to the bisection."""
    from belief_nlp.smoother.budget_start import START_SHARE, budget_warm_start

    sc, path = setting
    rb = RiskBudget(budget)
    top = rb.warm_level(K * len(sc.hazards))
    ladder = sorted({top * 0.9**i for i in range(13)} | ({sc.chi2} if sc.chi2 < top else set()), reverse=True)
    fits = []
    for level in ladder:
        try:
            w = warm_start(sc, path, K=K, chi2=level, verify_start=False)
        except InfeasibleStartError:
            continue
        if path_risk(sc, w.path, w.lam).step_time <= START_SHARE * budget:
            fits.append((level, w))
    assert 1 < len(fits) < len(ladder)            # some rungs too high to clear, or over the budget
    lowest, expected = fits[-1]
    got = budget_warm_start(sc, path, K, "minimal", rb)
    np.testing.assert_allclose(got.path.S, expected.path.S, rtol=1e-12, atol=0)
    np.testing.assert_allclose(got.lam, expected.lam, rtol=1e-12, atol=0)
    assert path_risk(sc, got.path, got.lam).step_time <= START_SHARE * budget
    # the highest fitting level (the start before session 18) senses more
    assert np.sum(np.linalg.slogdet(fits[0][1].path.S + np.eye(2))[1]) > \
        np.sum(np.linalg.slogdet(got.path.S + np.eye(2))[1])


# ------------------------------------------------------------------ smoothing
@pytest.mark.parametrize("method", ["ipopt", "ccp"])
def test_budget_is_met_by_the_independent_bound(setting, results, method):
    sc, _ = setting
    r = results[method]
    assert r.safe and r.risk is not None and r.risk.method == "optimal"
    recomputed = path_risk(sc, r.path, r.certificates).step_time
    assert recomputed <= BUDGET * (1 + 1e-9)
    assert math.isclose(r.risk.bound, recomputed, rel_tol=1e-9)
    # the allocation is proven pair by pair and fits the budget
    assert r.risk.allocation.shape == (K, len(sc.hazards))
    assert np.allclose(r.risk.allocation, tail(r.risk.levels))
    assert r.risk.allotted <= BUDGET * (1 + 1e-9)
    assert np.all(path_risk(sc, r.path, r.certificates).clearance >= r.risk.levels * (1 - 1e-6))
    # the verifier, told the levels and the budget, agrees
    rep = bn.verify(sc, r.path, certificates=r.certificates, levels=r.risk.levels, budget=BUDGET)
    assert rep.safe, rep.problems
    assert r.cost <= r.initial_cost


def test_methods_agree_and_beat_the_fixed_level_at_a_larger_budget(results):
    """IPOPT (exact g) and CCP (majorised g) reach the same optimum within 1 %;
    the fixed level certifies less than BUDGET, so the budgeted optimum cannot
    cost more (it is a feasible point of the budgeted problem)."""
    fixed, ip, cc = results["fixed"], results["ipopt"], results["ccp"]
    assert fixed.verification["risk_step_time"] < BUDGET
    assert abs(ip.cost - cc.cost) <= 0.01 * min(ip.cost, cc.cost)
    assert min(ip.cost, cc.cost) <= fixed.cost * (1 + 1e-3)


def test_uniform_allocation_spends_the_budget_evenly(setting, results):
    sc, path = setting
    r = bn.smooth(sc, path, method="ipopt", K=K, alpha=0.1, risk=0.45, allocation="uniform")
    lv = RiskBudget(0.45).uniform_level(r.path.K * len(sc.hazards))
    assert np.allclose(r.risk.levels, lv) and r.risk.method == "uniform"
    assert math.isclose(r.risk.allotted, 0.45, rel_tol=1e-9)
    assert path_risk(sc, r.path, r.certificates).step_time <= 0.45


def test_a_budget_the_path_cannot_meet_is_an_infeasible_start(setting):
    sc, path = setting
    with pytest.raises(InfeasibleStartError, match="risk budget"):
        bn.smooth(sc, path, method="ipopt", K=K, risk=1e-6, k_fallback=False)


def test_result_keeps_the_allocation_through_save_and_load(results, tmp_path):
    r = results["ipopt"]
    back = bn.SmoothResult.load(r.save(tmp_path / "r.json"))
    assert isinstance(back.risk, RiskAllocation) and back == r
    assert np.array_equal(back.risk.levels, r.risk.levels)
    assert "risk budget 0.3" in r.summary()


@pytest.mark.parametrize("method", ["auto", "sqp"])
def test_every_nlp_method_takes_a_budget(setting, method):
    """auto and SQP reach the budgeted problem through the same NLP form; the
    bound is recomputed from the path."""
    sc, path = setting
    r = bn.smooth(sc, path, method=method, K=8, alpha=0.1, risk=BUDGET)
    assert r.safe and r.risk is not None and r.cost <= r.initial_cost
    assert path_risk(sc, r.path, r.certificates).step_time <= BUDGET * (1 + 1e-9)


def test_fatrop_takes_an_optimal_allocation_as_a_running_sum(setting, results):
    """fatrop's stage form carries the budget row sum_kj g(tau_kj) <= Delta as
    a running sum (model.ocp_form): its answer is safe, within the budget by
    the bound recomputed from the path, and near IPOPT's optimum (fatrop
    stops 0.2-0.7 % above IPOPT on such problems; 3 % allows another local
    optimum nearby)."""
    from belief_nlp.methods.fatrop import available

    if not available():
        pytest.skip("this CasADi build has no fatrop plug-in")
    sc, path = setting
    r = bn.smooth(sc, path, method="fatrop", K=K, alpha=0.1, risk=BUDGET)
    assert r.safe and r.risk is not None and r.risk.method == "optimal" and r.cost <= r.initial_cost
    assert path_risk(sc, r.path, r.certificates).step_time <= BUDGET * (1 + 1e-9)
    assert bn.verify(sc, r.path, levels=r.risk.levels, budget=BUDGET).safe
    assert abs(r.cost - results["ipopt"].cost) <= 0.03 * results["ipopt"].cost


def test_verify_judges_a_budgeted_result_at_its_own_levels(setting, results):
    sc, _ = setting
    r = results["ipopt"]
    assert np.min(r.risk.levels) < sc.chi2                  # some pair spends more than the paper's level allows
    assert bn.verify(sc, r).safe                            # the result carries its levels and budget
    assert bn.verify(sc, r, budget=BUDGET).safe             # ... also when the budget is given again
    tight = bn.verify(sc, r, budget=0.5 * r.risk.bound)     # judged at its levels, over a smaller budget
    assert not tight.safe and all("budget" in p for p in tight.problems)
    assert not bn.verify(sc, r.path, certificates=r.certificates).safe     # the bare path at the fixed level is not


def test_result_saves_as_npz_and_smooth_reads_it(setting, results, tmp_path):
    """SmoothResult.save('.npz') as plans and paths do: reloads equal (the
    allocation and the certificates included) and is a path file for smooth."""
    sc, _ = setting
    r = results["ipopt"]
    f = r.save(tmp_path / "r.npz")
    back = bn.SmoothResult.load(f)
    assert back == r and np.array_equal(back.certificates, r.certificates)
    assert np.array_equal(back.risk.levels, r.risk.levels)
    again = bn.smooth(sc, f, method="ipopt", K=K, alpha=0.1, risk=BUDGET, max_iter=3)
    assert np.allclose(again.path.x[0], r.path.x[0]) and again.safe
    with pytest.raises(ValidationError, match="filename"):
        r.save(tmp_path / "r.txt")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(bn.ScenarioFileError):
        bn.SmoothResult.load(tmp_path / "bad.npz")


def test_budget_start_bisection_and_its_fallback(setting, monkeypatch):
    """The ladder is searched by bisection for its lowest rung that fits; a
    ladder out of order (a rung that cannot clear below one that can) falls
    back to the first rung from the top, so a fitting rung is never missed."""
    from types import SimpleNamespace

    from belief_nlp.smoother import budget_start

    sc, path = setting
    rb = RiskBudget(0.05)
    top = rb.warm_level(K * len(sc.hazards))
    ladder = sorted({top * 0.9**i for i in range(13)} | ({sc.chi2} if sc.chi2 < top else set()), reverse=True)

    def run(states):
        calls = []

        def fake_start(scenario, p, K, sensing, chi2, verify_start):
            i = ladder.index(chi2)
            calls.append(i)
            if states[i] == "x":
                raise InfeasibleStartError(f"rung {i} cannot clear")
            return SimpleNamespace(path=i, lam=None)

        monkeypatch.setattr(budget_start, "warm_start", fake_start)
        monkeypatch.setattr(budget_start, "path_risk", lambda scenario, i, lam: SimpleNamespace(
            step_time=0.01 if states[i] == "f" else 0.9))
        return budget_start.budget_warm_start(sc, path, K, "minimal", rb).path, calls

    ordered = "xxxfffff" + "o" * (len(ladder) - 8)
    got, calls = run(ordered)
    assert got == 7 and len(calls) <= 5                 # the lowest that fits, in a handful of starts
    out_of_order = "xfx" + "o" * (len(ladder) - 3)
    got, _ = run(out_of_order)
    assert got == 1
    with pytest.raises(InfeasibleStartError, match="certified bound is 0.9"):
        run("xx" + "o" * (len(ladder) - 2))
