"""The cascade's proximal step: the CCP step plus eps/2 (||dx||^2 + ||S - S~||^2
+ ||lam - lam~||^2), tried when Clarabel fails on the plain step. The term is
>= 0 and zero at the point, so the step still majorises the cost: its answer is
exactly safe and does not raise the cost."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import belief_nlp as bn
import belief_nlp.methods.ccp as ccp
import belief_nlp.methods.ccp_cascade as ccp_cascade
from belief_nlp.methods.ccp import PROXIMAL, compiled_step, initial_rho, solver_cascade
from belief_nlp.model.cvxpy_form import _square_root

from conftest import ccp_problem, paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=2)          # K = 10


_problem = ccp_problem


def test_square_root_is_exact_and_keeps_the_block_structure():
    """F^T F = H, and F has no entry outside H's connected blocks."""
    rng = np.random.default_rng(0)
    blocks = [rng.normal(size=(m, m)) for m in (3, 1, 4, 2)]
    H = sp.block_diag([b @ b.T for b in blocks]).tocsr()
    perm = rng.permutation(H.shape[0])               # blocks interleaved, as variables are in z
    H = H[perm][:, perm]
    F = _square_root(H)
    np.testing.assert_allclose((F.T @ F).toarray(), H.toarray(), atol=1e-12)
    reach = (abs(H) + sp.eye(H.shape[0])).toarray() != 0
    reach = np.linalg.matrix_power(reach.astype(int), H.shape[0]) > 0   # same block
    rows, cols = F.nonzero()
    # every entry of F couples variables of one block: F's row r is a combination within one block
    for r in set(rows):
        cs = cols[rows == r]
        assert reach[np.ix_(cs, cs)].all()


def test_proximal_step_is_a_tighter_majorant(small):
    """At the same point: plain optimum <= proximal optimum <= the step's value at
    the point itself (the term is >= 0 and zero there); both answers exactly safe."""
    sc, path = small
    model, prob = _problem(sc, path)
    z = prob.start
    rho = initial_rho(model, z)
    plain = compiled_step(model)[0]
    prox = compiled_step(model, proximal=PROXIMAL)[0]
    assert prox is not plain
    values = []
    for step in (plain, prox):
        step.set_point(z, rho, rho)
        step.problem.solve(solver="CLARABEL")
        assert step.problem.status == "optimal"
        answer = prob.check(model.tighten(step.layout.extract(np.asarray(step.z.value), z)))
        assert answer.safe
        assert model.cost(answer.point)[0] <= prob.cost0 * (1 + 1e-9)
        values.append(step.problem.value)
        step.z.value = step.layout.point_vector(z)
        at_point = step.problem.objective.value
    assert values[0] <= values[1] + 1e-7 * abs(values[1])
    assert values[1] <= at_point + 1e-7 * abs(at_point)
    assert values[1] > values[0] + 1e-12            # the term is active: the answers moved


def test_cascade_order_puts_the_proximal_step_before_scs():
    names = [(s, label) for s, label, _ in solver_cascade("CLARABEL")]
    i = names.index(("CLARABEL", "proximal"))
    assert names[:i] == [("CLARABEL", "library"), ("CLARABEL", "defaults")]
    if ("SCS", "high accuracy") in names:
        assert names.index(("SCS", "high accuracy")) > i


def test_run_goes_on_with_the_proximal_step_when_clarabel_fails(small, monkeypatch):
    """Every Clarabel solve of the plain step fails (as on the degenerate K = 40
    case of benchmarks/results/ccp.json): the run takes the proximal answers,
    stays monotone, ends converged and verified, and says which entry answered."""
    sc, path = small
    seen = []

    def failing(step, solver, options, time_left=None, reuse=False):     # every CVXPY solve of the plain step
        seen.append(solver)
        return "error: injected", None, 0.0, 0

    monkeypatch.setattr(ccp_cascade, "_solve", failing)
    monkeypatch.setattr(ccp, "solver_cascade",
                        lambda *a, **k: [e for e in solver_cascade(*a, **k) if e[0] == "CLARABEL"])
    r = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=60, tol=1e-5, keep_iterates=True,
                  active_set=False)                         # the CVXPY cascade only
    assert r.status == "converged", r.message
    assert seen                                  # the plain step's entries were tried first
    assert all(s["solver"] == "CLARABEL (proximal)" for s in r.stats["steps"])
    costs = [h.cost for h in r.history if h.accepted]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:]))
    assert r.cost < r.initial_cost
    assert bn.verify(sc, r.path).safe
    # the same problem without the fault reaches the same local optimum class
    free = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=60, tol=1e-5, active_set=False)
    assert r.cost == pytest.approx(free.cost, rel=2e-2)
