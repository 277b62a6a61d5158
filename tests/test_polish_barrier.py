"""The polish's monotone barrier stays at its mu_init (methods/ipopt.py,
POLISH_IPOPT_OPTIONS; docs/numerics.md, "The polish's barrier")."""

from __future__ import annotations

import pytest

import belief_nlp as bn
from belief_nlp.methods.ipopt import IpoptBackend


@pytest.mark.parametrize("tol", [1e-3, 1e-4, 1e-6])
def test_the_monotone_update_cannot_raise_the_polishs_barrier(tol):
    """IPOPT's monotone update sets mu to at least min(tol, compl_inf_tol) /
    (barrier_tol_factor + 1) (IpMonotoneMuUpdate::CalcNewMuAndTau; the
    barrier_tol_factor default is 10): for the polish's options at the
    run's tol that floor must not lie above mu_init, or the first update
    after a solved barrier problem raises mu."""
    opts = IpoptBackend().options({}, tol, "polish")
    assert opts["mu_strategy"] == "monotone"
    floor = min(opts["tol"], opts["compl_inf_tol"]) / (opts.get("barrier_tol_factor", 10.0) + 1.0)
    assert floor <= opts["mu_init"]


def test_a_polish_that_walked_off_its_answer_converges_to_the_ccp_polishs_cost():
    """paper-multi, planner seed 0, K = 40, alpha = 0.1: the polish met its
    barrier problem at mu = 1e-8 in 8 iterations, short of constr_viol_tol;
    IPOPT then set mu to 9.1e-6 and the polish's cost rose for 42
    iterations to its cap (measured). Now it converges, the answer is
    exactly safe and stationary in S, and auto's explicit CCP polish from it
    (a second method) lowers it by less than 1e-5."""
    sc = bn.load_scenario("paper-multi")
    ws = bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=0, noise="per_step").path, K=40)
    res = bn.smooth(sc, ws, alpha=0.1, method="ipopt")
    polish = res.stats["attempts"][-1]
    assert polish["formulation"] == "cholesky" and polish["return_status"] == "Solve_Succeeded"
    assert polish["iter_count"] < 50
    assert res.stats["sensing_stationary"] is True and bn.verify(sc, res.path).safe
    polished = bn.smooth(sc, ws, alpha=0.1, ccp_polish=10)          # auto: the same IPOPT answer, then CCP
    assert polished.method == "auto:ipopt+ccp"
    assert res.cost * (1 - 1e-5) <= polished.cost <= res.cost
