"""Belief maths against independent (inverse-based) computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from belief_nlp import belief

SETTINGS = settings(max_examples=60, deadline=None)


def spd(seed: int, d: int, lo: float = -2.0, hi: float = 1.0, scale: float = 1.0) -> np.ndarray:
    """Random SPD matrix: random rotation, eigenvalues 10^U(lo, hi), times scale."""
    rng = np.random.default_rng(seed)
    Q = np.linalg.qr(rng.normal(size=(d, d)))[0]
    M = scale * (Q * 10.0 ** rng.uniform(lo, hi, d)) @ Q.T
    return 0.5 * (M + M.T)


def psd(seed: int, d: int, rank: int, scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(d, rank))
    return scale * B @ B.T


seeds = st.integers(0, 2**32 - 1)
dims = st.sampled_from([2, 3])


def inv(M):
    return np.linalg.inv(M)


def sym_close(A, B, rtol=1e-8):
    return np.allclose(A, B, rtol=0, atol=rtol * max(np.max(np.abs(B)), 1e-300))


# ---------------------------------------------------------------- predict/update
def test_predict_adds_noise_batched():
    P = np.stack([spd(i, 2) for i in range(5)])
    W = spd(99, 2)
    assert np.array_equal(belief.predict(P, W), P + W)


@SETTINGS
@given(seeds, dims, st.integers(0, 3))
def test_update_matches_inverse_formula(seed, d, rank):
    Pp = spd(seed, d)
    S = psd(seed + 1, d, rank)
    ref = inv(inv(Pp) + S)
    out = belief.update(Pp, S)
    assert sym_close(out, ref)
    assert np.array_equal(out, out.T)
    # the posterior is never larger than the prior
    assert np.linalg.eigvalsh(Pp - out)[0] >= -1e-10 * np.linalg.norm(Pp)


@SETTINGS
@given(seeds, dims)
def test_update_is_stable_for_tiny_priors(seed, d):
    """update(c Pp, S / c) = c update(Pp, S): at c = 1e-9 the result must keep
    full relative accuracy (an inverse-based formula would lose it)."""
    Pp = spd(seed, d)
    S = psd(seed + 1, d, d)
    ref = belief.update(Pp, S)
    tiny = belief.update(1e-9 * Pp, S / 1e-9)
    assert sym_close(tiny / 1e-9, ref, rtol=1e-7)
    # and with a fixed, large S the tiny prior is barely changed
    P = belief.update(1e-9 * np.eye(d), 1e4 * np.eye(d))
    assert np.allclose(P, np.eye(d) / (1e9 + 1e4), rtol=1e-12, atol=0)


def test_update_with_zero_prior_and_zero_sensing():
    S = np.diag([1e4, 2e4])
    P = belief.update(np.zeros((2, 2)), S)
    assert np.all(np.isfinite(P)) and np.max(np.abs(P)) < 1e-250
    Pp = spd(3, 2)
    # no measurement: the prior comes back bit for bit (also inside a batch)
    assert np.array_equal(belief.update(Pp, np.zeros((2, 2))), Pp)
    batch = belief.update(np.stack([Pp, Pp]), np.stack([np.zeros((2, 2)), np.eye(2)]))
    assert np.array_equal(batch[0], Pp) and not np.array_equal(batch[1], Pp)
    # singular (rank-1) prior: the null direction stays (essentially) zero
    Pp1 = np.diag([1e-4, 0.0])
    P1 = belief.update(Pp1, np.eye(2))
    assert P1[0, 0] == pytest.approx(1 / (1e4 + 1), rel=1e-9) and abs(P1[1, 1]) < 1e-15


@SETTINGS
@given(seeds, dims)
def test_update_batched_equals_looped(seed, d):
    Pp = np.stack([spd(seed + i, d) for i in range(4)])
    S = np.stack([psd(seed + 10 + i, d, i % (d + 1)) for i in range(4)])
    batched = belief.update(Pp, S)
    looped = np.stack([belief.update(Pp[i], S[i]) for i in range(4)])
    assert np.allclose(batched, looped, rtol=1e-12, atol=1e-15)
    # 2-level batch shape
    assert belief.update(Pp.reshape(2, 2, d, d), S.reshape(2, 2, d, d)).shape == (2, 2, d, d)


# ------------------------------------------------------------- lossless sensing
@SETTINGS
@given(seeds, dims, st.integers(0, 3))
def test_lossless_sensing_inverts_update(seed, d, rank):
    Pp = spd(seed, d)
    S = psd(seed + 1, d, rank)
    P = inv(inv(Pp) + S)
    S_back = belief.lossless_sensing(Pp, P)
    assert np.allclose(S_back, inv(P) - inv(Pp), rtol=0, atol=1e-7 * max(1.0, np.max(np.abs(S))))
    assert np.allclose(S_back, S, rtol=0, atol=1e-7 * max(1.0, np.max(np.abs(S))))
    assert sym_close(belief.update(Pp, S_back), P, rtol=1e-9)
    assert belief.is_lossless(Pp, P)


@SETTINGS
@given(seeds, dims)
def test_lossless_test_agrees_with_psd_of_s(seed, d):
    """is_lossless(Pp, P) iff S = P^-1 - Pp^-1 is PSD, on random pairs."""
    Pp = spd(seed, d, -1, 0)
    P = spd(seed + 1, d, -1.5, 0.2)
    S = inv(P) - inv(Pp)
    eig = np.linalg.eigvalsh(0.5 * (S + S.T))
    if abs(eig[0]) < 1e-6 * np.max(np.abs(eig)):
        return  # too close to the boundary to call
    assert belief.is_lossless(Pp, P) == (eig[0] >= 0)
    Sl = belief.lossless_sensing(Pp, P)
    assert (np.linalg.eigvalsh(Sl)[0] >= 0) == (eig[0] >= 0)


def test_lossless_sensing_batched_and_tiny_scale():
    Pp = np.stack([spd(i, 2) for i in range(6)])
    P = np.stack([belief.update(Pp[i], psd(50 + i, 2, 2)) for i in range(6)])
    S = belief.lossless_sensing(Pp, P)
    looped = np.stack([belief.lossless_sensing(Pp[i], P[i]) for i in range(6)])
    assert np.allclose(S, looped, rtol=1e-12, atol=1e-12)
    assert np.array_equal(belief.is_lossless(Pp, P), np.ones(6, bool))
    # the same at 1e-9 scale: S scales by 1e9 exactly in exact arithmetic
    S_tiny = belief.lossless_sensing(1e-9 * Pp, 1e-9 * P)
    assert np.allclose(S_tiny * 1e-9, S, rtol=1e-7, atol=1e-7 * np.max(np.abs(S)))
    # equal priors and posteriors: no sensing
    assert np.allclose(belief.lossless_sensing(1e-9 * np.eye(2), 1e-9 * np.eye(2)), 0.0, atol=1e-3)
    # a posterior above the prior is not lossless and its S is indefinite
    assert not belief.is_lossless(np.eye(2), np.diag([0.5, 1.5]))
    assert np.linalg.eigvalsh(belief.lossless_sensing(np.eye(2), np.diag([0.5, 1.5])))[0] < 0


# ---------------------------------------------------------------- information
@SETTINGS
@given(seeds, dims, st.sampled_from([1.0, 1e-4, 1e-9]))
def test_information_cost_matches_slogdet(seed, d, scale):
    Pp = spd(seed, d, scale=scale)
    P = belief.update(Pp, psd(seed + 1, d, d, scale=1 / scale))
    ref = 0.5 * (np.linalg.slogdet(Pp)[1] - np.linalg.slogdet(P)[1])
    assert belief.information_cost(Pp, P) == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert belief.information_cost(Pp, P) >= -1e-12
    assert belief.information_cost(Pp, Pp) == 0.0
    assert isinstance(belief.information_cost(Pp, P), float)


def test_information_cost_units_and_batch():
    # halving the variance in both of 2 directions: 1/2 log 4 = log 2 nats = 1 bit
    assert belief.information_cost(np.eye(2), 0.5 * np.eye(2)) == pytest.approx(math.log(2))
    assert belief.information_cost(np.eye(2), 0.5 * np.eye(2)) / belief.NATS_PER_BIT == pytest.approx(1.0)
    Pp = np.stack([spd(i, 3) for i in range(5)])
    P = np.stack([belief.update(Pp[i], psd(i, 3, 2)) for i in range(5)])
    batched = belief.information_cost(Pp, P)
    assert batched.shape == (5,)
    assert np.allclose(batched, [belief.information_cost(Pp[i], P[i]) for i in range(5)], rtol=1e-13)
    assert np.allclose(belief.logdet(Pp), np.linalg.slogdet(Pp)[1], rtol=1e-12)


def test_steering_cost_is_paper_section_2b():
    """D_k = ||x_k - x_{k-1}||^2 + alpha * 1/2 (log det P_hat_k - log det P_k)."""
    x0, x1 = np.array([0.1, 0.2]), np.array([0.4, 0.6])
    Pp, P = np.diag([4e-4, 1e-4]), np.diag([1e-4, 1e-4])
    alpha = 0.3
    ref = 0.25 + alpha * 0.5 * math.log(4.0)
    assert belief.steering_cost(x0, x1, Pp, P, alpha) == pytest.approx(ref, rel=1e-13)
    # batched over steps, and the path total
    x = np.array([[0, 0], [0.1, 0], [0.1, 0.2]])
    Pps = np.stack([np.eye(2), 2 * np.eye(2), 3 * np.eye(2)])
    Ps = np.stack([np.eye(2), np.eye(2), np.eye(2)])
    steps = belief.steering_cost(x[:-1], x[1:], Pps[1:], Ps[1:], alpha)
    assert np.allclose(steps, [0.01 + alpha * math.log(2), 0.04 + alpha * math.log(3)])
    total, control, info = belief.path_steering_cost(x, Pps, Ps, alpha)
    assert control == pytest.approx(0.05) and info == pytest.approx(math.log(6))
    assert total == pytest.approx(np.sum(steps))


# --------------------------------------------------------------- matrix minimum
def _psd_ok(M, ref):
    return np.linalg.eigvalsh(0.5 * (M + M.T))[0] >= -1e-9 * np.linalg.norm(ref)


@SETTINGS
@given(seeds, dims)
def test_matrix_minimum_is_below_both_and_maximal(seed, d):
    P1, P2 = spd(seed, d), spd(seed + 1, d)
    M = belief.matrix_minimum(P1, P2)
    assert _psd_ok(P1 - M, P1) and _psd_ok(P2 - M, P2)
    assert np.linalg.eigvalsh(M)[0] > 0
    # maximal: in the simultaneous eigenbasis each direction touches one of
    # the two, so (P1 - M) P2^-1 (P2 - M) = 0
    prod = (P1 - M) @ inv(P2) @ (P2 - M)
    assert np.max(np.abs(prod)) <= 1e-8 * np.linalg.norm(P1) * np.linalg.norm(P2) * np.linalg.norm(inv(P2))
    # symmetric in its arguments
    assert np.allclose(belief.matrix_minimum(P2, P1), M, rtol=0, atol=1e-9 * np.linalg.norm(M))


@SETTINGS
@given(seeds, dims)
def test_matrix_minimum_of_ordered_pair_is_the_smaller(seed, d):
    P2 = spd(seed, d)
    P1 = belief.update(P2, psd(seed + 1, d, d))          # P1 <= P2
    assert np.allclose(belief.matrix_minimum(P1, P2), P1, rtol=0, atol=1e-10 * np.linalg.norm(P1))
    assert np.allclose(belief.matrix_minimum(P2, P1), P1, rtol=0, atol=1e-10 * np.linalg.norm(P1))
    assert np.allclose(belief.matrix_minimum(P2, P2), P2, rtol=0, atol=1e-12 * np.linalg.norm(P2))


def test_matrix_minimum_diagonal_batched_and_tiny():
    P1, P2 = np.diag([1.0, 4.0]), np.diag([2.0, 3.0])
    assert np.allclose(belief.matrix_minimum(P1, P2), np.diag([1.0, 3.0]))
    A = np.stack([spd(i, 2) for i in range(5)])
    B = np.stack([spd(10 + i, 2) for i in range(5)])
    batched = belief.matrix_minimum(A, B)
    looped = np.stack([belief.matrix_minimum(A[i], B[i]) for i in range(5)])
    assert np.allclose(batched, looped, rtol=1e-12, atol=1e-14)
    tiny = belief.matrix_minimum(1e-9 * A, 1e-9 * B)
    assert np.allclose(tiny / 1e-9, batched, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------- distances
def _bures_ref(P1, P2):
    r = scipy.linalg.sqrtm(P2)
    cross = np.real(np.trace(scipy.linalg.sqrtm(r @ P1 @ r)))
    return math.sqrt(max(np.trace(P1) + np.trace(P2) - 2 * cross, 0.0))


def _hellinger_ref(P1, P2, m1=None, m2=None):
    Pm = 0.5 * (P1 + P2)
    bc = np.linalg.det(P1) ** 0.25 * np.linalg.det(P2) ** 0.25 / np.sqrt(np.linalg.det(Pm))
    if m1 is not None:
        dm = np.asarray(m1) - np.asarray(m2)
        bc *= math.exp(-dm @ inv(Pm) @ dm / 8)
    return math.sqrt(max(1 - bc, 0.0))


@SETTINGS
@given(seeds, dims)
def test_wasserstein_matches_scipy_sqrtm(seed, d):
    P1, P2 = spd(seed, d), spd(seed + 1, d)
    w = belief.wasserstein_distance(P1, P2)
    assert w == pytest.approx(_bures_ref(P1, P2), rel=1e-6, abs=1e-9)
    assert belief.wasserstein_distance(P2, P1) == pytest.approx(w, rel=1e-6, abs=1e-9)
    assert belief.wasserstein_distance(P1, P1) == pytest.approx(0.0, abs=1e-6 * math.sqrt(np.trace(P1)))
    m1, m2 = np.arange(d) * 0.1, np.ones(d)
    full = belief.wasserstein_distance(P1, P2, m1, m2)
    assert full == pytest.approx(math.sqrt(w**2 + np.sum((m1 - m2) ** 2)), rel=1e-12)


def test_wasserstein_commuting_case_and_batch():
    # commuting covariances: || sqrt(D1) - sqrt(D2) ||_F
    P1, P2 = np.diag([1e-4, 9e-4]), np.diag([4e-4, 1e-4])
    assert belief.wasserstein_distance(P1, P2) == pytest.approx(math.sqrt(0.01**2 + 0.02**2), rel=1e-10)
    A = np.stack([spd(i, 3) for i in range(4)])
    B = np.stack([spd(20 + i, 3) for i in range(4)])
    assert np.allclose(belief.wasserstein_distance(A, B),
                       [belief.wasserstein_distance(A[i], B[i]) for i in range(4)], rtol=1e-12)
    with pytest.raises(ValueError):
        belief.wasserstein_distance(P1, P2, x1=[0, 0])


@SETTINGS
@given(seeds, dims)
def test_hellinger_matches_determinant_formula(seed, d):
    P1, P2 = spd(seed, d, -1, 0.5), spd(seed + 1, d, -1, 0.5)
    h = belief.hellinger_distance(P1, P2)
    assert 0.0 <= h <= 1.0
    assert h == pytest.approx(_hellinger_ref(P1, P2), rel=1e-7, abs=1e-8)
    assert belief.hellinger_distance(P2, P1) == pytest.approx(h, rel=1e-12, abs=1e-15)
    assert belief.hellinger_distance(P1, P1) == 0.0
    m1, m2 = np.zeros(d), np.full(d, 0.3)
    assert belief.hellinger_distance(P1, P2, m1, m2) == pytest.approx(_hellinger_ref(P1, P2, m1, m2), rel=1e-7)


def test_hellinger_scale_invariant_batched_and_bounded():
    A = np.stack([spd(i, 2) for i in range(5)])
    B = np.stack([spd(30 + i, 2) for i in range(5)])
    h = belief.hellinger_distance(A, B)
    assert np.allclose(h, [belief.hellinger_distance(A[i], B[i]) for i in range(5)], rtol=1e-12)
    # affine invariance: the same at 1e-9 scale (log-determinants, no cancellation)
    assert np.allclose(belief.hellinger_distance(1e-9 * A, 1e-9 * B), h, rtol=1e-9)
    # very different covariances: close to 1, never above
    far = belief.hellinger_distance(np.eye(2), 1e-12 * np.eye(2))
    assert 0.999 < far <= 1.0
    # a small perturbation gives a small (not cancelled-to-garbage) value
    eps = 1e-4
    small = belief.hellinger_distance(np.eye(2), (1 + eps) * np.eye(2))
    # H^2 ~ d eps^2 / 16 for P2 = (1 + eps) P1
    assert small == pytest.approx(math.sqrt(2 * eps**2 / 16), rel=1e-3)
