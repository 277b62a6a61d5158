"""fatrop (belief_nlp.methods.fatrop through smooth(method="fatrop"))."""

from __future__ import annotations

import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods.fatrop import available, map_status


pytestmark = pytest.mark.skipif(not available(), reason="this CasADi build has no fatrop plug-in")


# small_start (K = 10) and ipopt_from: tests/conftest.py


def test_listed_when_casadi_ships_it():
    assert "fatrop" in bn.available_methods()
    assert bn.get_method("fatrop").max_iter == 3000


def test_converges_verified_with_raw_stats(small_start, ipopt_from):
    """From the same warm start as IPOPT: a verified answer well below the
    start and within 1 % of IPOPT's (fatrop stops on its own tolerance at
    a point near, not at, IPOPT's: docs/numerics.md); the raw stats keep
    fatrop's own statistics and structure."""
    sc, ws = small_start
    res = bn.smooth(sc, ws, method="fatrop", alpha=1.0)
    ipo = ipopt_from(small_start, 1.0)
    assert res.method == "fatrop" and res.safe and bn.verify(sc, res.path).safe
    assert res.cost < 0.8 * res.initial_cost
    assert res.cost == pytest.approx(ipo.cost, rel=1e-2)
    att = res.stats["attempts"]
    assert att[0]["formulation"] == "logchol" and att[0]["iter_count"] > 0
    assert res.stats["iter_count"] == sum(a["iter_count"] for a in att)
    # one history record per fatrop solve, numbered by fatrop's own iteration count
    assert [h.iteration for h in res.history[1:]] == [sum(a["iter_count"] for a in att[:i + 1])
                                                      for i in range(len(att))]
    # nit is the iterations fatrop performed, not the records (was 2 for 164 iterations at K = 20)
    assert res.nit == res.stats["iter_count"] > len(res.history) - 1


def test_iteration_limit_is_fatrops_own(small_start):
    sc, ws = small_start
    res = bn.smooth(sc, ws, method="fatrop", alpha=1.0, max_iter=5)
    assert res.status == "max_iter" and res.stats["iter_count"] <= 5 and res.safe
    assert res.nit == res.stats["iter_count"]


def test_bad_solver_options_are_our_error(small_start):
    sc, ws = small_start
    with pytest.raises(ValidationError, match="solver_options") as exc:
        bn.smooth(sc, ws, method="fatrop", solver_options={"no_such_fatrop_option": 1.0})
    assert "no_such_fatrop_option" in str(exc.value)
    with pytest.raises(ValidationError, match="solver_options"):
        bn.smooth(sc, ws, method="fatrop", solver_options={"tol": "tight"})
    with pytest.raises(ValidationError, match="solver"):
        bn.smooth(sc, ws, method="fatrop", solver="IPOPT")


def test_status_map():
    assert map_status("Success") == "converged"
    assert map_status("Maximum_Iterations_Exceeded") == "max_iter"
    assert map_status("SOLVER_RET_LIMITED (flag 1)") == "max_iter"
    assert map_status("Maximum_WallTime_Exceeded") == "time_limit"
    assert map_status("SOLVER_RET_UNKNOWN (flag 4)") == "solver_failed"


@pytest.fixture(scope="module")
def failing_start():
    """paper-multi seed 3 at K = 20: fatrop's first attempt ended solver_failed
    after 174 iterations at alpha 1 (session 19)."""
    sc = bn.load_scenario("paper-multi")
    plan = bn.plan(sc, n_nodes=500, seed=3, noise="per_step")
    return sc, bn.warm_start(sc, plan.path, K=20)


def test_a_failed_first_stage_is_rescued_with_a_lower_first_barrier(failing_start):
    """The restart from the start with mu_init 1e-3 converges, verified, near
    IPOPT's optimum (a second solver); the attempts say what ran."""
    sc, ws = failing_start
    res = bn.smooth(sc, ws, method="fatrop", alpha=1.0)
    assert res.status == "converged" and res.safe and bn.verify(sc, res.path).safe
    ipo = bn.smooth(sc, ws, method="ipopt", alpha=1.0)
    assert res.cost == pytest.approx(ipo.cost, rel=1e-2) and res.cost < res.initial_cost
    first = [a["return_status"] for a in res.stats["attempts"] if a["formulation"] == "logchol"]
    assert first[-1] == "Success"


def test_the_rescue_keeps_the_runs_iteration_limit(failing_start):
    """Its own limit is what the first attempt left of max_iter."""
    sc, ws = failing_start
    res = bn.smooth(sc, ws, method="fatrop", alpha=1.0, max_iter=200)
    assert res.stats["iter_count"] <= 200 + 2      # fatrop's limit m allows m + 1 per solve
    assert sum(a["iter_count"] for a in res.stats["attempts"]) == res.stats["iter_count"]
