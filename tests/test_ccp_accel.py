"""Accelerated CCP (``accelerate=True``, the default): each step may first be
linearised at an extrapolated point. The step's feasible set is an inner
approximation of the true one at *any* linearisation point, so its answer is
exactly safe even when that point is not; the step is taken only when it
lowers the cost."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods.ccp import _extrapolate, compiled_step, initial_rho

from conftest import ccp_problem, paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=2)          # K = 10


_problem = ccp_problem


def test_extrapolated_point_is_a_valid_linearisation_point(small):
    """S stays PSD, lam >= 0, Q is the Kalman recursion of S (so Y~ > 0), and
    beta = 0 gives the point back."""
    sc, path = small
    model, prob = _problem(sc, path)
    z = prob.start
    z_prev = z.copy()
    z_prev.x[1:-1] += 0.3
    z_prev.S[1:] *= 3.0
    z_prev.lam *= 2.0
    same = _extrapolate(model, z, z, 0.7)
    np.testing.assert_allclose(same.x, z.x)
    np.testing.assert_allclose(same.S, z.S, rtol=1e-10, atol=1e-12)
    y = _extrapolate(model, z, z_prev, 0.9)
    assert np.all(np.linalg.eigvalsh(y.S[1:]) >= -1e-12)
    assert np.all(y.lam >= 0)
    np.testing.assert_allclose(y.Q, model.tighten(y).Q, rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(y.Y[1:]) > 0)
    np.testing.assert_allclose(y.x[1:-1], z.x[1:-1] - 0.9 * 0.3)


def test_a_step_linearised_at_an_unsafe_point_answers_a_safe_point(small):
    """The inner-approximation property the acceleration rests on: linearised
    at a point the exact check refuses (means pushed into the hazards, half
    the sensing), the step's answer is exactly safe."""
    sc, path = small
    model, prob = _problem(sc, path)
    z = prob.start
    step, _, _ = compiled_step(model)
    for shift, sensing, seed in ((0.03, 0.5, 3), (0.0, 0.3, 0), (0.01, 0.5, 1)):
        rng = np.random.default_rng(seed)
        y = z.copy()
        y.x[1:-1] += shift / model.data.sigma * rng.normal(size=y.x[1:-1].shape)
        y.S[1:] *= sensing
        y = model.tighten(y)
        assert not prob.check(y).safe
        rho = initial_rho(model, y)
        step.set_point(y, rho, rho)
        step.problem.solve(solver="CLARABEL")
        assert step.problem.status in ("optimal", "optimal_inaccurate")
        answer = model.tighten(step.layout.extract(np.asarray(step.z.value), y))
        chk = prob.check(answer)
        assert chk.safe, (shift, sensing, chk.margin, chk.target)
        # and the independent verification of the mapped path agrees
        assert bn.verify(sc, model.to_path(chk.point)).safe


def test_accelerated_run_is_monotone_safe_and_no_worse(small):
    """The default (accelerated) run: some steps extrapolated, costs never rise,
    the answer verified, and its cost no higher than the plain run's (to the
    stopping tolerance) in no more iterations."""
    sc, path = small
    fast = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, keep_iterates=True)
    plain = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=100, tol=1e-5, accelerate=False)
    assert fast.status == plain.status == "converged"
    taken = [s["solver"] for s in fast.stats["steps"]]
    assert any("extrapolated" in str(t) for t in taken)
    assert not any("extrapolated" in str(s["solver"]) for s in plain.stats["steps"])
    costs = [r.cost for r in fast.history if r.accepted]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:]))
    assert bn.verify(sc, fast.path).safe
    assert fast.cost <= plain.cost * (1 + 1e-4)
    assert fast.nit <= plain.nit


def test_accelerate_must_be_a_bool(small):
    sc, path = small
    with pytest.raises(bn.ValidationError, match="accelerate"):
        bn.smooth(sc, path, method="ccp", accelerate="yes")
