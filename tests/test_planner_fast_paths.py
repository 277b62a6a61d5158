"""The planner's fast paths give the answers of the exact, per-edge computations.

* the all-pairs screen (:mod:`belief_nlp.planner.screen`): every certificate
  is a pair the exact minimiser proves clear, every witness a pair whose
  exact minimum is below the threshold;
* the checker with ordered parent candidates picks the same first clear
  parent as deciding every edge, and decides the other edges in full;
* the sub-interval layers and the exact fallback agree with the exact
  check on edges that graze the obstacles;
* the closed-form 2-D edge-cost kernels on entries are bit for bit the
  generic batched kernels, and the planner's nearest node is the brute-force
  argmin of the edge cost;
* the shrink exponent is the smallest number of halvings that clears the
  ellipse, by the exact point distances.
"""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import belief, geometry
from belief_nlp.planner import IGRRTStar
from belief_nlp.planner.collision import CollisionChecker
from belief_nlp.planner.kernels import chol_factors, congruence_eigvals, lower_congruence_eig2
from belief_nlp.planner.metrics import EdgeMetric

MARGIN = 1e-6


def _edges(sc, rng, n, near_obstacles=False):
    """Random transitions; with ``near_obstacles`` the means start and end
    close to obstacle vertices and the covariances are small, so that the
    cheap layers leave many pairs open."""
    d = sc.dim
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    if near_obstacles:
        verts = np.concatenate([h.vertices for h in sc.hazards if h.vertices is not None])
        x0 = verts[rng.integers(len(verts), size=n)] + rng.normal(0, 0.03, (n, d))
        x1 = x0 + rng.normal(0, 0.05, (n, d))
        scale = 10 ** rng.uniform(-7, -4, (n, 1, 1))
    else:
        x0 = lo + (hi - lo) * rng.random((n, d))
        x1 = x0 + rng.normal(0, 0.15, (n, d))
        scale = 10 ** rng.uniform(-6, -3, (n, 1, 1))
    A = rng.normal(size=(n, d, d))
    P0 = (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(d)) * scale
    W = np.broadcast_to(sc.W, (n, d, d)).copy()
    return x0, P0, x1, W


def _exact(sc, x0, P0, x1, W):
    """(lower, upper) of every (edge, hazard) pair, hazards as the checker's
    screen orders them (obstacles first, then walls)."""
    hazards = [h for h in sc.hazards if h.A.shape[0] > 1] + [h for h in sc.hazards if h.A.shape[0] == 1]
    ps = geometry.PolytopeSet.build(hazards)
    return geometry.transition_bounds(x0, P0, x1, W, ps)


@pytest.mark.parametrize("name", ["paper-multi", "tutorial", "cube3d"])
@pytest.mark.parametrize("near", [False, True])
def test_screen_verdicts_agree_with_the_exact_minimum(name, near):
    sc = bn.load_scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    thr = checker.thr
    rng = np.random.default_rng(11)
    x0, P0, x1, W = _edges(sc, rng, 300, near)
    hit, clear = checker.screen.certify(x0, x1, P0 + W)
    wit = checker.screen.end_witness(x1, P0 + W)
    if wit is not None:
        hit = hit | wit
    lower, upper = _exact(sc, x0, P0, x1, W)
    assert not np.any(hit & clear)
    assert np.all(lower[clear] >= thr)                 # every certificate is a proven clearance
    assert np.all(upper[hit] < thr)                    # every witness is a real collision
    assert clear.mean() > 0.3 and hit.any()            # and both do work


@pytest.mark.parametrize("name", ["paper-multi", "tutorial"])
def test_axis_parallel_segments_are_witnessed_only_when_they_collide(name):
    """Segments parallel to a face (axis-aligned moves next to the walls and
    box obstacles): a witness only where the exact minimum is below the
    threshold (a parallel face the segment runs outside of is no hit)."""
    sc = bn.load_scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    rng = np.random.default_rng(5)
    lo, hi = sc.domain.bounding_box()
    n = 200
    x0 = lo + (hi - lo) * rng.uniform(0.05, 0.95, size=(n, sc.dim))
    step = np.zeros((n, sc.dim))
    axis = rng.integers(0, sc.dim, n)
    step[np.arange(n), axis] = rng.uniform(-0.1, 0.1, n)
    x1 = np.clip(x0 + step, lo, hi)
    P0 = np.repeat(1e-9 * np.eye(sc.dim)[None], n, 0)
    W = np.repeat(np.asarray(sc.W, float)[None], n, 0)
    hit, clear = checker.screen.certify(x0, x1, P0 + W)
    lower, upper = _exact(sc, x0, P0, x1, W)
    assert np.all(upper[hit] < checker.thr) and np.all(lower[clear] >= checker.thr)
    assert clear.any()


@pytest.mark.parametrize("name", ["paper-multi", "tutorial", "cube3d"])
def test_checker_agrees_with_the_exact_check_on_grazing_edges(name):
    """The sub-interval layers and the exact fallback, where the screen leaves
    most pairs open: the same verdict as the exact per-edge check."""
    sc = bn.load_scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    rng = np.random.default_rng(5)
    x0, P0, x1, W = _edges(sc, rng, 400, near_obstacles=True)
    mine = checker.transitions_clear(x0, P0, x1, W)
    ps = geometry.PolytopeSet.build(sc.hazards)
    exact = geometry.transitions_clear(x0, P0, x1, W, ps, sc.chi2, margin=sc.chi2 * MARGIN).all(axis=1)
    assert np.array_equal(mine, exact)
    assert 0.05 < mine.mean() < 0.95
    assert checker.stats["edges_refined"] > 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ordered_parents_give_the_first_clear_one(seed):
    """``ordered = k``: the first clear one of the first k edges is the one a
    full decision finds (later ones may come back False: not decided), the
    rest as decided in full."""
    sc = bn.load_scenario("paper-multi")
    rng = np.random.default_rng(seed)
    x0, P0, x1, W = _edges(sc, rng, 60, near_obstacles=bool(seed % 2))
    full = CollisionChecker(sc, MARGIN).transitions_clear(x0, P0, x1, W)
    for k in (1, 7, 30, 60):
        out = CollisionChecker(sc, MARGIN).transitions_clear(x0, P0, x1, W, ordered=k)
        first = np.flatnonzero(full[:k])
        got = np.flatnonzero(out[:k])
        assert np.all(full[:k][got])                   # whatever comes back clear is clear
        assert got[:1].tolist() == first[:1].tolist()   # and the first clear one is found
        assert np.array_equal(out[k:], full[k:])


@pytest.mark.parametrize("metric", ["entropy", "hellinger"])
def test_entry_kernels_are_the_generic_kernels_bit_for_bit(metric):
    rng = np.random.default_rng(3)
    n = 200
    A = rng.normal(size=(n, 2, 2))
    P = (A @ np.swapaxes(A, 1, 2) + 0.05 * np.eye(2)) * 10 ** rng.uniform(-8, -2, (n, 1, 1))
    W = np.array([[2e-4, 3e-5], [3e-5, 1e-4]])
    w = rng.uniform(0.01, 0.5, n)
    C = P[0] * 3.0
    _, C_Linv, _, _ = chol_factors(C)
    m = EdgeMetric(metric, alpha=0.3, info_unit="nats", W_edge=W)
    s11, s12, s22 = P[:, 0, 0] + w * W[0, 0], P[:, 0, 1] + w * W[0, 1], P[:, 1, 1] + w * W[1, 1]
    t = (C_Linv[0, 0], C_Linv[1, 0], C_Linv[1, 1])
    small, big = lower_congruence_eig2(s11, s12, s22, *t)
    ref = congruence_eigvals(P, w, W, C_Linv)
    assert np.array_equal(small, ref[:, 0]) and np.array_equal(big, ref[:, 1])
    assert np.array_equal(m.nearest_info2(s11, s12, s22, *t), m.nearest_info(P, w, C, C_Linv))
    lossless, info = m.edges2(s11, s12, s22, *t)
    lossless_ref, info_ref = m.edges_to(P, w, C, None, C_Linv)
    assert np.array_equal(lossless, lossless_ref) and np.array_equal(info, info_ref)
    # from one belief Q to every node, the factors per node
    L = np.linalg.cholesky(P)
    Linv = np.zeros_like(L)
    Linv[:, 0, 0], Linv[:, 1, 1] = 1 / L[:, 0, 0], 1 / L[:, 1, 1]
    Linv[:, 1, 0] = -L[:, 1, 0] / (L[:, 0, 0] * L[:, 1, 1])
    Q = P[1]
    lossless, info = m.edges2(Q[0, 0] + w * W[0, 0], Q[0, 1] + w * W[0, 1], Q[1, 1] + w * W[1, 1],
                              Linv[:, 0, 0], Linv[:, 1, 0], Linv[:, 1, 1])
    lossless_ref, info_ref = m.edges_from(Q, w, P, L, Linv)
    assert np.array_equal(lossless, lossless_ref) and np.array_equal(info, info_ref)


@pytest.mark.parametrize("noise", ["per_step", "per_metre"])
def test_nearest_node_is_the_brute_force_argmin(noise):
    """The planner's nearest (cached prior entries, closed-form kernel) is the
    node a brute-force loop over belief.py's definitions picks."""
    sc = bn.load_scenario("paper-multi")
    planner = IGRRTStar(sc, n_nodes=150, seed=4, noise=noise, backend="numpy")
    planner.plan()
    tree = planner.tree_
    live = tree.live_arrays()
    rng = np.random.default_rng(9)
    W = planner.W_edge
    for _ in range(20):
        xs = rng.random(2)
        B = rng.normal(size=(2, 2))
        Ps = (B @ B.T + 0.1 * np.eye(2)) * 10 ** rng.uniform(-6, -2)
        dist = np.linalg.norm(xs - live.x, axis=1)
        _, Ls_inv, _, _ = chol_factors(Ps)
        s = planner._priors(live, dist if planner.per_metre else None)
        D = dist + planner.metric.weight * planner.metric.nearest_info2(s[0], s[1], s[2], Ls_inv[0, 0],
                                                                         Ls_inv[1, 0], Ls_inv[1, 1])
        brute = []
        for i in range(live.idx.size):
            P_hat = live.P[i] + (dist[i] if planner.per_metre else 1.0) * W
            mm = belief.matrix_minimum(P_hat, Ps)
            brute.append(dist[i] + planner.metric.weight * float(belief.information_cost(P_hat, mm)))
        brute = np.array(brute)
        assert np.allclose(D, brute, rtol=1e-9, atol=1e-12)
        assert np.argmin(D) == np.argmin(brute) or np.isclose(brute[np.argmin(D)], brute.min(), rtol=1e-12)


@pytest.mark.parametrize("name", ["paper-multi", "cube3d"])
def test_shrink_exponent_is_the_smallest_clearing_one(name):
    sc = bn.load_scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    ps = geometry.PolytopeSet.build(sc.hazards)
    rng = np.random.default_rng(1)
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    seen = set()
    for _ in range(150):
        x = lo + (hi - lo) * rng.random(sc.dim)
        B = rng.normal(size=(sc.dim, sc.dim))
        P = (B @ B.T + 0.1 * np.eye(sc.dim)) * 10 ** rng.uniform(-5, -1)
        k = checker.shrink_exponent(x, P)
        d2 = geometry.ellipse_clearances(x[None], P[None], ps, sc.chi2)[0] + sc.chi2   # exact, per hazard
        if k is None:
            assert np.min(d2) <= 1e-12                                                # the mean is in a hazard
            seen.add("inside")
            continue
        seen.add(k > 0)
        assert np.min(d2) * 2.0 ** k >= checker.thr * (1 - 1e-9)
        if k:
            assert np.min(d2) * 2.0 ** (k - 1) < checker.thr * (1 + 1e-9)
    assert {True, False} <= seen
