"""The SQP baseline (belief_nlp.methods.sqp: Uno's filter-SQP through CasADi)."""

from __future__ import annotations

import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods.sqp import map_status

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def hand_start():
    sc, path = paper_multi_path_pair()
    return sc, bn.warm_start(sc, path)


def test_sqp_reaches_ipopts_optimum_from_the_same_start(hand_start):
    """Two NLP solvers on one NLP: the SQP answer is converged, verified and
    within 0.1 % of IPOPT's (both polish on the exact Cholesky NLP)."""
    sc, ws = hand_start
    sqp = bn.smooth(sc, ws, method="sqp", alpha=1.0)
    ipo = bn.smooth(sc, ws, method="ipopt", alpha=1.0)
    assert sqp.method == "sqp" and sqp.solver == "Uno" and sqp.status == "converged" and sqp.success
    assert sqp.safe and bn.verify(sc, sqp.path).safe
    assert sqp.cost == pytest.approx(ipo.cost, rel=1e-3)
    assert sqp.cost < sqp.initial_cost
    att = sqp.stats["attempts"]
    assert att[0]["formulation"] == "logchol" and map_status(att[0]["return_status"]) == "converged"
    assert sqp.stats["iter_count"] == sum(a["iter_count"] for a in att) > 0
    assert sqp.stats["restoration"] is None          # Uno's plug-in does not report it: no made-up zero


def test_status_mapping():
    assert map_status("Converged with feasible KKT point") == "converged"
    assert map_status("Maximum_Iterations_Exceeded") == "max_iter"
    assert map_status("Maximum_WallTime_Exceeded") == "time_limit"
    assert map_status("Terminated with infeasible point") == "solver_failed"


def test_bad_solver_and_options_are_our_errors(hand_start):
    sc, ws = hand_start
    with pytest.raises(ValidationError) as e:
        bn.smooth(sc, ws, method="sqp", solver="IPOPT")
    assert e.value.field == "solver"
    for bad in ({"preset": "byrd"}, {"max_iterations": [10]}):     # CasADi passes Uno's options unchecked
        with pytest.raises(ValidationError) as e:
            bn.smooth(sc, ws, method="sqp", solver_options=bad)
        assert e.value.field == "solver_options"
