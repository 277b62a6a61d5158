"""The polish's switch-off (NLPProblem.switch_off,
model/nlp_matrices.switched_off): the sensing a first-stage answer holds at
the floor is fixed at 0, either as whole columns of L at the floor or, where
a diagonal at the floor has sensing below it, by re-factoring S without its
floor-level eigen-directions."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.model.nlp_matrices import switched_off

F = 1e-2 * 1.1          # the polish's level: floor (1 + slack)


def _random_factors(rng, n: int, d: int) -> np.ndarray:
    """Well-conditioned factors: no eigenvalue of L L^T near the floor by chance."""
    L = np.tril(0.3 * rng.normal(size=(n, d, d)))
    L[:, range(d), range(d)] = np.abs(L[:, range(d), range(d)]) + 1.0
    return L


def _without_floor(S: np.ndarray) -> np.ndarray:
    """S without its eigen-directions at most F^2 (an independent reading: eigh per matrix)."""
    w, U = np.linalg.eigh(S)
    keep = w > F ** 2
    return (U[:, keep] * w[keep]) @ U[:, keep].T


@pytest.mark.parametrize("d", [2, 3])
def test_columns_at_the_floor_are_zeroed_and_the_rest_kept_bit_for_bit(d):
    """Columns whose norm is at the floor (the floor's own sensing, nothing
    below the diagonal): zeroed; every other entry is the input's."""
    rng = np.random.default_rng(d)
    L = _random_factors(rng, 300, d)
    small = rng.random((300, d)) < 0.4
    for n, j in zip(*np.nonzero(small)):
        L[n, j:, j] = 0.0
        L[n, j, j] = 1e-2 * rng.uniform(0.999, 1.05)
    out, off = switched_off(L, F)
    assert np.array_equal(off, small)
    assert np.array_equal(out, np.where(small[:, None, :], 0.0, L))


@pytest.mark.parametrize("d", [2, 3])
def test_a_floored_diagonal_with_sensing_below_it_is_refactored(d):
    """A diagonal at the floor with sensing below it: the result is lower
    triangular, reproduces S without its floor-level directions (checked by
    eigh of each S), and has one zero column per dropped direction."""
    rng = np.random.default_rng(10 + d)
    L = _random_factors(rng, 200, d)
    j = rng.integers(0, d - 1, size=200)                  # a column with sensing below its diagonal
    L[np.arange(200), j, j] = 1e-2
    L[np.arange(200), j + 1, j] = rng.choice([-1.0, 1.0], 200) * rng.uniform(0.3, 1.0, 200)
    out, off = switched_off(L, F)
    S = L @ L.transpose(0, 2, 1)
    assert np.all(np.triu(out, 1) == 0.0) and np.all(out.transpose(0, 2, 1)[off] == 0.0)
    for n in range(200):
        Sr = _without_floor(S[n])
        assert off[n].sum() == d - np.linalg.matrix_rank(Sr, tol=F ** 2)
        np.testing.assert_allclose(out[n] @ out[n].T, Sr, rtol=0, atol=1e-10 * np.abs(S[n]).max())


def test_the_sensing_direction_may_tilt_after_the_switch_off():
    """2-D, L = [[floor, 0], [-0.36, 0.63]] (the step that made the polish
    creep): mostly axis-2 sensing with a floor-level direction. The result
    senses along S's main eigen-direction, with column 1 off and column 0
    free to tilt (L_11 != 0), not pinned to axis 2."""
    L = np.array([[[1e-2, 0.0], [-0.36, 0.63]]])
    out, off = switched_off(L, F)
    S = L[0] @ L[0].T
    w, U = np.linalg.eigh(S)
    assert off.tolist() == [[False, True]] and out[0, 0, 0] != 0.0
    np.testing.assert_allclose(out[0] @ out[0].T, w[1] * np.outer(U[:, 1], U[:, 1]), atol=1e-15)


def test_a_polish_that_crept_along_a_rotation_converges():
    """paper-multi, planner seed 0, K = 20, alpha = 1: the first stage's last
    step has L_11 at the floor with L_21 = -0.36 below it. Kept on, the
    polish crept along (L_21, L_22) for its 50 iterations (S does not
    change along it as L_11 -> 0); switched off, it converges."""
    sc = bn.load_scenario("paper-multi")
    ws = bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=0, noise="per_step").path, K=20)
    res = bn.smooth(sc, ws, method="ipopt", alpha=1.0)
    polish = [a for a in res.stats["attempts"] if a["formulation"] == "cholesky"]
    assert res.stats["polish_status"] == "Solve_Succeeded" and polish[0]["iter_count"] < 50
    assert res.status == "converged" and bn.verify(sc, res.path).safe and res.cost <= res.initial_cost
