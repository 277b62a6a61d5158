"""A polish stopped at its cap while its cost was still falling gets one
more run of its cap from where it stopped (methods/nlp_stage.py still_lowering,
methods/nlp_engine.py _polish_further)."""

from __future__ import annotations

import types

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods import nlp_stage
from belief_nlp.methods.nlp_stage import STOPS, Stage


@pytest.fixture(scope="module")
def capped_case():
    """paper-multi, planner seed 3 with max_radius 1.5, K = 20, alpha 0.1:
    its polish is still lowering its cost at the cap of 50 and converges 36
    iterations later (measured with the padded first stage, session 24; the
    demo's plan, this test's case before, now polishes in 5)."""
    sc = bn.load_scenario("paper-multi").with_options(alpha=0.1)
    planned = bn.plan(sc, n_nodes=500, seed=3, noise="per_step", max_radius=1.5)
    assert planned.success
    return sc, bn.warm_start(sc, planned.path, K=20)


def test_a_polish_still_lowering_its_cost_at_the_cap_goes_on(capped_case):
    """The capped polish goes on and converges at the cost an uncapped one
    reaches (polish=100, one run), verified; a second extension is never run."""
    sc, ws = capped_case
    res = bn.smooth(sc, ws, method="ipopt")
    longer = bn.smooth(sc, ws, method="ipopt", polish=100)
    polish = [(a["return_status"], a["iter_count"]) for a in res.stats["attempts"] if a["formulation"] == "cholesky"]
    assert polish[0] == ("Maximum_Iterations_Exceeded", 50) and len(polish) == 2 and polish[1][1] <= 50
    assert res.stats["polish_status"] == "Solve_Succeeded" and res.status == "converged"
    assert res.cost == pytest.approx(longer.cost, rel=1e-5) and bn.verify(sc, res.path).safe


def _stage_and_history(costs: list[float], status: str = STOPS["max_iter"]):
    stage = Stage(status=status, used=len(costs), z=np.zeros(3), duals=(np.zeros(3), np.zeros(1)))
    problem = types.SimpleNamespace(history=[types.SimpleNamespace(cost=c) for c in [9.0] * 5 + costs])
    return problem, stage


def test_still_lowering_reads_the_polishs_own_last_iterations():
    cap = 20
    falling = list(np.linspace(2.40, 2.30, cap))                 # 5e-3 over the last 10: going on
    flat = [2.3] * (cap - 11) + list(2.3 - 1e-8 * np.arange(11))  # creeping at its answer
    assert nlp_stage.still_lowering(*_stage_and_history(falling), cap)
    assert not nlp_stage.still_lowering(*_stage_and_history(flat), cap)
    assert not nlp_stage.still_lowering(*_stage_and_history(falling, "Solve_Succeeded"), cap)
    assert not nlp_stage.still_lowering(*_stage_and_history(falling[:15]), cap)        # stopped below its cap
