"""The polish's switch-off (NLPProblem.switch_off): columns of L whose
diagonal sits at the log-Cholesky floor are fixed at 0, and the sensing
below such a diagonal moves onto the later columns
(model/nlp_matrices.without_columns)."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.model.nlp_matrices import without_columns


def _random_factors(rng, n: int, d: int) -> np.ndarray:
    L = np.tril(rng.normal(size=(n, d, d)))
    L[:, range(d), range(d)] = np.abs(L[:, range(d), range(d)]) + 0.1
    return L


@pytest.mark.parametrize("d", [2, 3])
def test_the_other_columns_keep_s_from_their_diagonal_down(d):
    """Every on column j of the result reproduces S = L L^T from row j down
    (the Cholesky recursion, checked against S itself); switched-off
    columns are 0; the result is lower-triangular."""
    rng = np.random.default_rng(d)
    L = _random_factors(rng, 200, d)
    off = rng.random((200, d)) < 0.4
    out = without_columns(L, off)
    S, S2 = L @ L.transpose(0, 2, 1), out @ out.transpose(0, 2, 1)
    assert np.all(np.triu(out, 1) == 0.0) and np.all(out.transpose(0, 2, 1)[off] == 0.0)
    for n in range(200):
        for j in np.flatnonzero(~off[n]):
            np.testing.assert_allclose(S2[n, j:, j], S[n, j:, j], rtol=1e-12, atol=1e-12)


def test_a_column_with_nothing_below_its_diagonal_leaves_the_others_bit_for_bit():
    rng = np.random.default_rng(0)
    L = _random_factors(rng, 50, 3)
    L[:, 1:, 0] = 0.0                      # column 0: its diagonal alone
    off = np.zeros((50, 3), bool)
    off[:, 0] = True
    out = without_columns(L, off)
    assert np.all(out[:, :, 0] == 0.0) and np.array_equal(out[:, :, 1:], L[:, :, 1:])


def test_the_sensing_below_a_floored_diagonal_moves_to_the_next_column():
    """2-D: L = [[floor, 0], [a, b]] senses axis 2 by a^2 + b^2; switched
    off, the step senses axis 2 alone, by the same amount."""
    L = np.array([[[1e-2, 0.0], [-0.36, 0.63]]])
    out = without_columns(L, np.array([[True, False]]))
    np.testing.assert_allclose(out[0], [[0.0, 0.0], [0.0, np.hypot(0.36, 0.63)]], rtol=1e-15)


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
