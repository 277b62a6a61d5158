"""Certified safety geometry: the rigorous lower bound of the transition oracle.

Every pair's minimum over s of dist2(x(s), P(s)) must lie in [lower, upper]
(``transition_bounds`` / ``TransitionMinimum.lower`` and ``.dist2``), checked
against an independent oracle (dense sampling of s, 2001 samples, refined by
a ternary search; point-to-polygon / point-to-triangle distances in whitened
coordinates, tests/test_geometry.py), on random 2-D and 3-D cases with tiny
and needle covariances and pairs that touch; acceptance (``transitions_clear``,
the planner) only on the lower bound; an iteration limit leaves pairs
undecided, never passed.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

import belief_nlp as bn
from belief_nlp import geometry as geo
from belief_nlp.planner.collision import CollisionChecker
from belief_nlp.polytope import Polytope
from test_geometry import (CHI2, FAST, hull_polytope, oracle_transition_min, points2, points3, polytope_3d,
                           random_spd, random_transitions, rel)

SAMPLES = 2001


def hard_transitions(rng: np.random.Generator, n: int, d: int, poly: Polytope):
    """Random transitions, two thirds of them with hard data: tiny start
    covariances (1e-9), needle covariances (eigenvalue ratio 1e8) for P_0
    and W, and mean paths through a vertex of the polytope (they touch)."""
    x0, P0, x1, W = random_transitions(rng, n, d, p=(1e-6, 1e-1))
    k = n // 6
    P0[:k] = 1e-9 * np.eye(d) if d == 2 else random_spd(rng, k, d, 1e-10, 1e-9)
    needle = np.full((k, d), 1e-10)
    needle[:, 0] = 1e-2
    Q, _ = np.linalg.qr(rng.normal(size=(k, d, d)))
    P0[k:2 * k] = np.einsum("nij,nj,nkj->nik", Q, needle, Q)
    W[2 * k:3 * k] = np.einsum("nij,nj,nkj->nik", Q, 0.1 * needle, Q)
    # through a vertex: x(t) = v for some t in (0, 1)
    v = poly.vertices[rng.integers(0, poly.vertices.shape[0], k)]
    u = rng.normal(size=(k, d))
    t = rng.uniform(0.1, 0.9, size=(k, 1))
    x0[3 * k:4 * k] = v - t * u
    x1[3 * k:4 * k] = v + (1 - t) * u
    return x0, P0, x1, W


def _condition(P0, W):
    ev = np.linalg.eigvalsh(np.concatenate([P0, P0 + W]))
    return np.max((ev[:, -1] / np.maximum(ev[:, 0], 1e-300)).reshape(2, -1), axis=0)


def assert_bracketed(poly: Polytope, x0, P0, x1, W, tight: float | None = 1e-5):
    """lower <= true minimum <= upper for every pair, and (when ``tight``)
    the lower bound close to the minimum: within ``tight`` (1e-5) relative for
    every pair whose covariances have condition <= 1e6, and within 1e-8 for
    most pairs. A needle (condition 1e8) only has to be bracketed: the
    rounding bound of its certificate value grows with the condition (1e-5
    relative; 1e-3 at a sliver's sharp vertex, whose certificate is large),
    and in 3-D the generic face solves may lose the minimum (the bounds stay
    valid; a threshold between them leaves the pair undecided)."""
    tm = geo.transition_minimiser(x0, P0, x1, W, [poly])
    lower, upper = tm.lower[:, 0], tm.dist2[:, 0]
    sampled, refined = oracle_transition_min(poly, x0, P0, x1, W, samples=SAMPLES)
    # the oracle's own rounding (whitening a needle) is ~1e-12 relative
    assert np.all(lower <= sampled + 1e-9 * (1 + sampled)), np.max((lower - sampled) / (1 + sampled))
    assert np.all(lower <= refined + 1e-9 * (1 + refined))
    # upper is attained at some s; the oracle's 3-D least-distance solves agree to ~1e-7 on flat hulls
    assert np.all(upper >= refined - 1e-6 * (1 + refined)), np.max((refined - upper) / (1 + refined))
    assert np.all(lower >= 0) and np.all(lower <= upper)
    assert not tm.limited.any()
    if tight is not None:
        gap = rel(lower, refined)
        assert np.all(gap[_condition(P0, W) <= 1e6] < tight), np.max(gap[_condition(P0, W) <= 1e6])
        assert np.median(gap) < 1e-8
    return tm


@settings(FAST, max_examples=60)
@given(pts=points2, seed=st.integers(0, 2**32 - 1))
def test_bounds_bracket_the_minimum_2d(pts, seed):
    """30 transitions per random polygon (1800 cases), two thirds of them hard."""
    poly = hull_polytope(pts)
    rng = np.random.default_rng(seed)
    assert_bracketed(poly, *hard_transitions(rng, 30, 2, poly))


@settings(FAST, max_examples=20)
@given(pts=points3, seed=st.integers(0, 2**32 - 1), box=st.booleans())
def test_bounds_bracket_the_minimum_3d(pts, seed, box):
    """12 transitions per box / random hull in 3-D (240 cases), half hard."""
    rng = np.random.default_rng(seed)
    poly = polytope_3d(pts, rng, box)
    assert_bracketed(poly, *hard_transitions(rng, 12, 3, poly))


def test_seeded_bounds_2d_and_3d():
    """Seeded numpy companion of the hypothesis tests: 900 planar pairs on
    the paper's obstacles and 150 generic pairs on random hulls."""
    rng = np.random.default_rng(7)
    for poly in bn.load_scenario("paper-multi").obstacles:
        assert_bracketed(poly, *hard_transitions(rng, 150, 2, poly))
    for _ in range(5):
        pts = rng.uniform(-1, 1, (9, 3))
        poly = Polytope.from_vertices(pts[ConvexHull(pts).vertices])
        assert_bracketed(poly, *hard_transitions(rng, 30, 3, poly))


def test_near_flat_hull_regression():
    """The hull with a near-duplicate vertex (1.8e-9 apart) that made the
    generic path drop a vertex and overestimate the minimum by 30 %: exact
    again, and the lower bound never above the truth."""
    pts = np.array([[0, 0, .5], [1.82080317e-9, .5, .5], [0, .5, .5], [.5, 0, .5], [.5, .5, 0]])
    poly = Polytope.from_vertices(pts[ConvexHull(pts).vertices])
    rng = np.random.default_rng(0)
    x0, P0, x1, W = random_transitions(rng, 10, 3, p=(1e-5, 1e-1))
    tm = assert_bracketed(poly, x0, P0, x1, W)
    _, refined = oracle_transition_min(poly, x0, P0, x1, W)
    assert np.all(rel(tm.dist2[:, 0], refined) < 1e-7)


SLIVER_3D = [np.array([[-1, 0, -1], [-1, -1, -1], [0, -1, 0.625], [0, y, 0.5]]) for y in (0.0, 1.0)]


@pytest.mark.parametrize("pts", SLIVER_3D, ids=["y0", "y1"])
def test_sliver_tetrahedron_regression(pts):
    """Hypothesis's 3-D counterexamples (seed 5180242): flat tetrahedra whose
    opposite faces meet at sharp edges, a needle W and a 1e-9 start. The
    face solves through G_SS = A_S P A_S^T lost the minimiser's edge (its
    rows' residuals round to ~eps |G| |mu| with mu ~ 1e10), a vertex with a
    negative multiplier won, and the bracket's tangent was no tangent: the
    lower bound came out 0 against a true 2e8. Now within 1e-5 of it."""
    poly = Polytope.from_vertices(pts.astype(float))
    rng = np.random.default_rng(5180242)
    x0, P0, x1, W = hard_transitions(rng, 12, 3, poly)
    tm = assert_bracketed(poly, x0, P0, x1, W)
    assert tm.lower[4, 0] > 1.7e8
    # the static distance and certificate at the minimiser (the same face solves)
    s = tm.s[4, 0]
    x, P = x0[4] + s * (x1[4] - x0[4]), P0[4] + s * W[4]
    assert rel(geo.squared_mahalanobis_distance(x, P, [poly])[0, 0], tm.dist2[4, 0]) < 1e-7
    lam = geo.ellipse_certificate(x, P, poly.A, poly.b)
    v = poly.A.T @ lam
    assert rel(2 * lam @ (poly.A @ x - poly.b) - v @ P @ v, tm.dist2[4, 0]) < 1e-6


# local hypothesis seed 2085 of test_transition_clearance_3d_vs_sampling:
# hulls with coordinates of 2e-7 next to 0 and 1, so that two or three of
# their faces have nearly equal normals and offsets 2e-7 apart
SLIVER_HULLS = [
    ([[0.5, 0, 2e-7], [0, 2e-7, 1], [2e-7, 1, 2e-7], [2e-7, 2e-7, 1], [2e-7, 2e-7, 2e-7]], 7),
    ([[0.125, 0, 2e-7], [0, 2e-7, 1], [2e-7, 1, 2e-7], [2e-7, 2e-7, 1], [2e-7, 2e-7, 2e-7]], 7),
    ([[7.8125e-3, 0, 2e-7], [2e-7, 0, 2e-7], [2e-7, -1, 2e-7], [1, 2e-7, 0], [2e-7, 2e-7, 2e-7],
      [2e-7, 2e-7, -1]], 9),
]


@pytest.mark.parametrize("pts, pair", SLIVER_HULLS, ids=["vertex", "vertex-narrow", "off-vertex"])
def test_near_parallel_faces_regression(pts, pair):
    """At the vertex of two near-parallel faces the face solve gives mu of
    +-2e9 (+-2e11 on the third hull). It used to give the minimisation over
    s wrong slopes (stopped 2.9e-6 above the minimum), a certificate with a
    negative entry (lower bound 0: a clear pair not called clear), and on
    the third hull a point off the vertex, outside the hull, whose distance
    was 1.2e-7 *below* the minimum. Now the certificate and the slopes come
    from the candidate of the largest dual value, and a vertex's computed
    point must lie inside every plane: exact, tight and decided."""
    pts = np.array(pts)
    poly = Polytope.from_vertices(pts[ConvexHull(pts).vertices])
    x0, P0, x1, W = random_transitions(np.random.default_rng(0), 10, 3, p=(1e-5, 1e-1))
    tm = assert_bracketed(poly, x0, P0, x1, W)
    _, refined = oracle_transition_min(poly, x0, P0, x1, W, samples=SAMPLES)
    assert np.all(rel(tm.dist2[:, 0], refined) < 1e-8)
    assert rel(tm.lower[pair, 0], refined[pair]) < 1e-8
    thr = 0.999 * refined[pair]
    assert geo.transitions_clear(x0[pair], P0[pair], x1[pair], W[pair], [poly], thr)[0, 0]


def test_strict_evaluation_agrees_on_regular_hulls():
    """The generic path's two rules for a pair -- the nearest feasible
    candidate's certificate and slopes (the fast rule) and the largest dual
    value's (the strict rule, run where the fast one is in doubt) -- pick
    the same candidate at a regular minimiser: on random hulls and boxes in
    3-D, the same values, slopes and certificates."""
    from belief_nlp.geometry.generic import _evaluate, _prepare, _whitened
    rng = np.random.default_rng(4)
    polys = [Polytope.box([0.0, 0.0, 0.0], [0.3, 0.5, 0.2])]
    for _ in range(3):
        pts = rng.uniform(-1, 1, (9, 3))
        polys.append(Polytope.from_vertices(pts[ConvexHull(pts).vertices]))
    ps = geo.PolytopeSet.build(polys)
    x0, P0, x1, W = random_transitions(rng, 200, 3, p=(1e-4, 1e-1))
    s = rng.uniform(0, 1, 200)
    x, P = x0 + s[:, None] * (x1 - x0), P0 + s[:, None, None] * W
    c, G, midx = _prepare(x, P, ps)
    m = len(polys)
    dc = -np.einsum("mfd,nd->nmf", ps.A, x1 - x0).reshape(c.shape)
    dG = np.einsum("mfd,nde,mge->nmfg", ps.A, W, ps.A).reshape(G.shape)
    B = _whitened(P, ps)
    fast = _evaluate(c, G, midx, ps, dc, dG, True, B)
    strict = _evaluate(c, G, midx, ps, dc, dG, True, B, strict=True)
    assert np.isfinite(fast.g).all() and (fast.g > 0).sum() > 0.9 * 200 * m
    for a, b in ((fast.g, strict.g), (fast.g1, strict.g1), (fast.g2, strict.g2)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    # the certificates: where more than d facets meet (a triangulated hull's
    # vertex) several subsets carry one, so compare what they prove, their
    # dual values -2 lam^T c - lam^T G lam, with the distance itself
    for e in (fast, strict):
        assert np.all(e.lam >= 0)
        q = -2 * np.einsum("nf,nf->n", e.lam, c) - np.einsum("nf,nfg,ng->n", e.lam, G, e.lam)
        np.testing.assert_allclose(q, fast.g, rtol=1e-9, atol=1e-12)


def test_sliver_triangle_regression():
    """Hypothesis's 2-D counterexample (seed 196): a triangle with a 1.8 deg
    vertex. Planar path: the certificate's rounding bound counted
    (|A|^T lam)^T |P| (|A|^T lam), but A^T lam cancels there (lam ~ 7e9), so
    the lower bound sat 4e-5 below the minimum (1.685e7); the bound now uses
    |A^T lam|. Generic path (the 3-D code, on request in 2-D): the vertex's
    value cancelled in mu^T G mu, failed its consistency check, and the
    minimiser stopped at s = 0 with 16x the minimum."""
    pts = np.array([[0.96875, 0.0], [1.0, 0.0], [-0.5, 1.0]])
    poly = Polytope.from_vertices(pts[ConvexHull(pts).vertices])     # (hull_polytope's assume is Hypothesis-only)
    rng = np.random.default_rng(196)
    x0, P0, x1, W = hard_transitions(rng, 30, 2, poly)
    tm = assert_bracketed(poly, x0, P0, x1, W)
    _, refined = oracle_transition_min(poly, x0, P0, x1, W, samples=SAMPLES)
    assert rel(tm.lower[11, 0], refined[11]) < 1e-6
    gen = geo.transition_minimiser(x0, P0, x1, W, [poly], want_lam=True, _generic=True)
    assert np.all(rel(gen.dist2[:, 0], refined) < 1e-6)
    assert rel(geo.transition_bounds(x0[11], P0[11], x1[11], W[11], [poly])[0][0, 0], refined[11]) < 1e-6


def test_degenerate_vertices_carry_valid_certificates():
    """Vertices where more than d facets meet (a square pyramid's apex):
    the certificate of the winning face is >= 0 and proves the minimum."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [.5, .5, 1.0]])
    apex = Polytope.from_vertices(V)
    rng = np.random.default_rng(3)
    x0 = np.array([.5, .5, 1.5]) + rng.normal(scale=0.1, size=(50, 3))
    x1 = x0 + rng.normal(scale=0.05, size=(50, 3))
    P0 = random_spd(rng, 50, 3, 1e-4, 1e-2)
    W = random_spd(rng, 50, 3, 1e-6, 1e-3)
    tm = assert_bracketed(apex, x0, P0, x1, W)
    assert np.all(rel(tm.lower[:, 0], tm.dist2[:, 0]) < 1e-8)


def test_threshold_at_the_minimum_is_never_passed_on_the_upper_bound():
    """Pairs scaled so that their minimum is exactly the threshold (they
    touch it): clear only where the lower bound proves it, and then the
    oracle agrees up to rounding."""
    rng = np.random.default_rng(11)
    sc = bn.load_scenario("paper-multi")
    for poly in sc.obstacles[:3]:
        x0, P0, x1, W = random_transitions(rng, 200, 2, p=(1e-6, 1e-2))
        _, refined = oracle_transition_min(poly, x0, P0, x1, W)
        ok = refined > 1e-6
        c = (refined / CHI2)[ok]                  # dist2 scales as 1/c when P0 and W do
        x0, x1, P0, W = x0[ok], x1[ok], P0[ok] * c[:, None, None], W[ok] * c[:, None, None]
        lower, upper = geo.transition_bounds(x0, P0, x1, W, [poly], CHI2)
        clear = geo.transitions_clear(x0, P0, x1, W, [poly], CHI2)[:, 0]
        assert np.array_equal(clear, lower[:, 0] >= CHI2)
        _, truth = oracle_transition_min(poly, x0, P0, x1, W)
        assert np.all(truth[clear] >= CHI2 * (1 - 1e-9))
        assert np.all(lower[:, 0] <= truth * (1 + 1e-9))


def iteration_limited_case():
    """Random hulls in 3-D with thresholds just below each pair's minimum
    (clear by 1e-4 relative): the generic bracketing needs a few rounds."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(-1, 1, (10, 3))
    poly = Polytope.from_vertices(pts[ConvexHull(pts).vertices])
    x0, P0, x1, W = random_transitions(rng, 300, 3, p=(1e-4, 1e-2), w=(1e-4, 1e-2))
    full = geo.transition_minimiser(x0, P0, x1, W, [poly])
    return poly, x0, P0, x1, W, full


@pytest.mark.parametrize("max_iter", [0, 1])
def test_iteration_limit_leaves_pairs_undecided(max_iter):
    poly, x0, P0, x1, W, full = iteration_limited_case()
    undecided_seen = 0
    for margin in (1e-4, 1e-2):
        thr = float(np.median(full.dist2)) * (1 - margin)
        tm = geo.transition_minimiser(x0, P0, x1, W, [poly], max_iter=max_iter, threshold=thr)
        clear = geo.transitions_clear(x0, P0, x1, W, [poly], thr, max_iter=max_iter)
        und = ~tm.decided
        undecided_seen += int(und.sum())
        assert not np.any(clear[und])                               # never passed
        assert np.array_equal(clear, tm.lower >= thr)
        assert np.all(clear <= (full.lower >= thr))                 # limited acceptances are real ones
        assert np.all(tm.lower <= full.dist2 * (1 + 1e-9))          # still rigorous
        assert np.all(tm.dist2 >= full.lower * (1 - 1e-9))
    assert undecided_seen > 0
    # without a threshold a limited pair is marked undecided too
    tm = geo.transition_minimiser(x0, P0, x1, W, [poly], max_iter=max_iter)
    assert np.array_equal(tm.decided, ~tm.limited) and tm.limited.any()
    assert np.all(tm.lower <= full.dist2 * (1 + 1e-9))


def test_planner_check_rejects_undecided_pairs(monkeypatch):
    """The planner's exact layer accepts on the lower bound only: pairs the
    bounds cannot decide are collisions and are counted."""
    sc = bn.load_scenario("cube3d")
    checker = CollisionChecker(sc, 1e-6)
    rng = np.random.default_rng(2)
    n = 400
    x0 = rng.uniform(0, 1, (n, 3))
    x1 = x0 + rng.normal(scale=0.1, size=(n, 3))
    P0 = random_spd(rng, n, 3, 1e-5, 1e-3)
    W = np.broadcast_to(sc.W, (n, 3, 3)).copy()
    ok = checker.transitions_clear(x0, P0, x1, W)
    assert checker.stats["pairs_exact"] > 0 and checker.stats["undecided_pairs"] == 0

    calls = []
    bounds = geo.transition_bounds

    def undecided(*args, **kwargs):                 # bounds that straddle every threshold
        lower, upper = bounds(*args, **kwargs)
        calls.append(lower.size)
        return np.zeros_like(lower), np.full_like(upper, np.inf)

    monkeypatch.setattr(geo, "transition_bounds", undecided)
    checker2 = CollisionChecker(sc, 1e-6)
    ok2 = checker2.transitions_clear(x0, P0, x1, W)
    assert sum(calls) == checker2.stats["pairs_exact"] == checker2.stats["undecided_pairs"] > 0
    assert np.all(ok2 <= ok) and ok2.sum() < ok.sum()


def test_planner_with_forced_iteration_limit(monkeypatch):
    """plan() with the exact minimiser given no rounds: undecided pairs
    are counted in the result's stats and the path is still verified safe."""
    monkeypatch.setattr(CollisionChecker, "exact_max_iter", 0)
    sc = bn.load_scenario("cube3d")
    res = bn.plan(sc, n_nodes=300, seed=0)
    assert res.stats["undecided_pairs"] == res.stats["collision_undecided_pairs"]
    assert res.stats["undecided_pairs"] > 0
    if res.path is not None:
        assert bn.verify(sc, res.path).safe


@pytest.mark.parametrize("name", ["paper-multi", "cube3d"])
def test_planner_unchanged_where_nothing_is_undecided(name, monkeypatch):
    """With nothing undecided, deciding on the lower bound plans exactly what
    deciding on the minimum found (the previous rule) planned."""
    sc = bn.load_scenario(name)
    certified = bn.plan(sc, n_nodes=300, seed=0)
    assert certified.stats["undecided_pairs"] == 0

    bounds = geo.transition_bounds

    def upper_only(*args, **kwargs):
        _, upper = bounds(*args, **kwargs)
        return upper, upper

    monkeypatch.setattr(geo, "transition_bounds", upper_only)
    before = bn.plan(sc, n_nodes=300, seed=0)
    assert certified.cost == before.cost
    assert np.array_equal(certified.path.x, before.path.x)
