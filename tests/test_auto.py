"""method="auto": IPOPT first, CCP from the best safe point when IPOPT's answer is not taken."""

from __future__ import annotations

import pytest

import belief_nlp as bn

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=2)        # K = 10


def test_a_converged_ipopt_answer_is_taken(small):
    sc, path = small
    res = bn.smooth(sc, path, method="auto", alpha=1.0, ccp_polish=0)
    assert res.method == "auto:ipopt" and res.success and res.safe
    ref = bn.smooth(sc, path, method="ipopt", alpha=1.0)
    assert res.cost == pytest.approx(ref.cost, rel=1e-9)
    assert res.stats["stages"] == ["ipopt"]
    # a CCP polish of IPOPT's answer: never above it, the stages say so
    polished = bn.smooth(sc, path, method="auto", alpha=1.0, ccp_polish=10)
    assert polished.method == "auto:ipopt+ccp" and polished.stats["stages"] == ["ipopt", "ccp polish"]
    assert polished.cost <= ref.cost * (1 + 1e-12) and polished.safe


def test_ccp_continues_when_ipopt_stops_early(small):
    sc, path = small
    # IPOPT may only take 5 iterations: it stops unconverged and CCP finishes from its best safe point
    res = bn.smooth(sc, path, method="auto", alpha=1.0, solver_options={"max_iter": 5}, max_iter=200)
    assert res.method == "auto:ccp" and res.stats["stages"] == ["ipopt", "ccp"]
    assert res.safe and res.cost <= res.initial_cost
    its = [h.iteration for h in res.history]
    assert its == sorted(its) and len(set(its)) == len(its) and res.nit <= 200
    ccp_only = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=200)
    assert res.cost == pytest.approx(ccp_only.cost, rel=2e-2)       # the same local optimum region


def test_polish_never_raises_the_cost(small):
    sc, path = small
    plain = bn.smooth(sc, path, method="auto", alpha=1.0, ccp_polish=0)
    polished = bn.smooth(sc, path, method="auto", alpha=1.0, ccp_polish=3)
    assert polished.cost <= plain.cost * (1 + 1e-12) and polished.safe
    assert polished.method in ("auto:ipopt+ccp", "auto:ipopt")


def test_the_ipopt_stage_takes_ipopts_method_options(small):
    """``ipopt_options`` are the first stage's method options: auto's IPOPT
    stage with floor 5e-3 is method "ipopt" with floor 5e-3 (the same
    iterations and point); bad keys and values are our errors naming the field."""
    sc, path = small
    alone = bn.smooth(sc, path, method="ipopt", alpha=1.0, floor=5e-3)
    auto = bn.smooth(sc, path, alpha=1.0, ipopt_options={"floor": 5e-3}, ccp_polish=0)
    default = bn.smooth(sc, path, alpha=1.0, ccp_polish=0)
    assert auto.method == "auto:ipopt" and auto.stats["ipopt"]["iter_count"] == alone.stats["iter_count"]
    assert auto.cost == alone.cost and bn.verify(sc, auto.path).safe
    assert [a["iter_count"] for a in auto.stats["ipopt"]["attempts"]] != \
        [a["iter_count"] for a in default.stats["ipopt"]["attempts"]] or auto.cost != default.cost
    with pytest.raises(bn.ValidationError, match="ipopt_options.*'flor' is not an option"):
        bn.smooth(sc, path, ipopt_options={"flor": 5e-3})
    with pytest.raises(bn.ValidationError, match="ipopt_options.*'polish'"):
        bn.smooth(sc, path, ipopt_options={"polish": -1})
    with pytest.raises(bn.ValidationError, match="ipopt_options"):
        bn.smooth(sc, path, ipopt_options=[("floor", 5e-3)])


def test_a_polish_step_clarabel_cannot_answer_ends_the_polish():
    """alpha = 1e-6 (information nearly free of cost): Clarabel's answers to
    the polish's first step are refused (non-monotone by 1e-3). The rest of
    the cascade (CVXPY's compile, SCS at high accuracy) took 110 s for that
    one step; the polish now ends there and IPOPT's answer stands."""
    sc = bn.load_scenario("paper-multi")
    planned = bn.plan(sc, n_nodes=300, seed=0, noise="per_step", alpha=0.1)
    res = bn.smooth(sc, planned, method="auto", alpha=1e-6, ccp_polish=10)
    ipo = bn.smooth(sc, planned, method="ipopt", alpha=1e-6)
    assert res.method == "auto:ipopt+ccp" and res.status == "converged" and res.safe
    assert res.cost <= ipo.cost * (1 + 1e-12)
    ccp = res.stats["ccp"]
    assert ccp["compile"] == "not needed"                      # CVXPY's step never built
    tried = {(a["solver"], a["settings"]) for s in ccp["steps"] for a in s.get("attempts", [])}
    assert tried and tried <= {("CLARABEL", "active set"), ("CLARABEL", "full step")}


def test_alpha_zero_has_no_nlp_minimiser_auto_answers_with_ccp(small_start):
    """alpha = 0: sensing costs nothing, the NLP has no minimiser (IPOPT
    stopped on NaN after 180 iterations). The NLP methods say so; auto goes
    to CCP at once, which answers as method "ccp" does."""
    sc, ws = small_start
    for method in [m for m in ("ipopt", "sqp", "fatrop") if m in bn.available_methods()]:
        with pytest.raises(bn.ValidationError) as err:
            bn.smooth(sc, ws, method=method, alpha=0.0)
        assert err.value.field == "alpha" and "no minimiser" in str(err.value)
    res = bn.smooth(sc, ws, method="auto", alpha=0.0)
    ccp = bn.smooth(sc, ws, method="ccp", alpha=0.0)
    assert res.method == "auto:ccp" and res.stats["ipopt_skipped"] and res.safe
    assert res.status == ccp.status and res.cost == pytest.approx(ccp.cost, rel=1e-9)
