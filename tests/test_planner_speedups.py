"""The planner's issue-21 speed-ups compute what the plain computations compute.

* the block sample stream gives :meth:`BeliefSampler.draw`'s samples bit for
  bit (box and non-box domains, goal bias, 2-D and 3-D), and the inverse
  Cholesky entries :func:`chol_factors` gives;
* the screen's split form (certificates for every edge, segment witnesses
  for the open ones) is :meth:`HazardScreen.certify`'s brute-force Liang-Barsky
  verdict on every edge.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.planner.collision import CollisionChecker
from belief_nlp.planner.kernels import chol_factors
from belief_nlp.planner.sampling import BeliefSampler
from belief_nlp.polytope import Polytope


def _triangle_scenario():
    """A 2-D stand-in with a non-box domain and target (rejection sampling)."""
    dom = Polytope.from_vertices([[0.0, 0.0], [2.0, 0.0], [0.0, 1.5]])
    tgt = Polytope.from_vertices([[0.2, 0.2], [0.6, 0.2], [0.2, 0.5]])
    return SimpleNamespace(dim=2, domain=dom, target=tgt)


@pytest.mark.parametrize("which, goal_bias", [("paper-multi", 0.0), ("paper-multi", 0.3), ("triangle", 0.2),
                                              ("cube3d", 0.1)])
def test_sample_stream_is_the_scalar_draw(which, goal_bias):
    sc = _triangle_scenario() if which == "triangle" else bn.load_scenario(which)
    sampler = BeliefSampler(sc, (1e-9, 0.1), 10.0, goal_bias)
    r1, r2 = np.random.default_rng(11), np.random.default_rng(11)
    stream = sampler.stream(r2)
    for _ in range(700):                       # more than two blocks
        x, P = sampler.draw(r1)
        y, Q, lin = stream.next()
        assert np.array_equal(x, y) and np.array_equal(P, Q)
        if sc.dim == 2:
            Linv = chol_factors(P)[1]
            assert list(lin) == [Linv[0, 0], Linv[1, 0], Linv[1, 1]]
        else:
            assert lin is None


def _edges(sc, rng, n):
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    x0 = lo + (hi - lo) * rng.random((n, 2))
    x1 = x0 + rng.normal(0, 0.3, (n, 2))
    A = rng.normal(size=(n, 2, 2))
    P1 = (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(2)) * 10 ** rng.uniform(-6, -2, (n, 1, 1))
    return x0, x1, P1


def _segment_meets(x0, x1, A, b):
    """Brute force: does the segment meet {y : A y <= b}? (a dense scan of the segment)"""
    t = np.linspace(0.0, 1.0, 4001)[:, None]
    pts = x0 + t * (x1 - x0)
    return bool(np.any(np.all(pts @ A.T <= b + 1e-12, axis=1)))


def test_split_screen_is_the_full_screen():
    sc = bn.load_scenario("paper-multi")
    screen = CollisionChecker(sc, 1e-6).screen
    hazards = [h for h in sc.hazards if h.A.shape[0] > 1] + [h for h in sc.hazards if h.A.shape[0] == 1]
    rng = np.random.default_rng(4)
    x0, x1, P1 = _edges(sc, rng, 300)
    hit, clear = screen.certify(x0, x1, P1)
    clear2, seg = screen.clearances(x0, x1, P1)
    rows = rng.permutation(300)[:120]
    assert np.array_equal(clear, clear2 & ~hit)
    assert np.array_equal(screen.segment_hits(seg, rows), hit[rows])
    # the witnesses against a dense scan of the segments (exact up to the scan's resolution)
    for e in rng.permutation(300)[:60]:
        for k, h in enumerate(hazards):
            if hit[e, k] != _segment_meets(x0[e], x1[e], h.A, h.b):
                # only a segment that grazes a corner can differ from the scan
                assert abs(np.max(np.minimum(x0[e] @ h.A.T - h.b, x1[e] @ h.A.T - h.b))) < 1e-3
    assert hit.any() and clear.any()


def test_distances_are_the_einsum_bit_for_bit():
    from belief_nlp.planner.iteration import _distances
    from belief_nlp.planner.tree import BeliefTree

    rng = np.random.default_rng(2)
    tree = BeliefTree(2, capacity=8)
    for i in range(300):
        tree.add(rng.random(2), np.eye(2) * 1e-3, i - 1, float(i), 0.0, 0.0, goal=False)
    tree.set_live(rng.permutation(300)[:120], False)
    live = tree.live_arrays()
    for _ in range(20):
        x = rng.random(2)
        diff = x - tree.x[live.idx]
        assert np.array_equal(_distances(x, live), np.sqrt(np.einsum("ij,ij->i", diff, diff)))
    assert np.array_equal(live.P, tree.P[live.idx])


@pytest.mark.parametrize("name", ["paper-multi", "quad"])
def test_pruning_between_improvements_would_drop_nothing(name):
    """The planner prunes only when the best cost improves: after every
    attempt, no live node other than the root is above the bound of the
    best cost the attempt started from (costs only fall, hopeless arrivals
    are dropped at once)."""
    import math

    from belief_nlp.planner import IGRRTStar

    seen = []

    class Checked(IGRRTStar):
        def _iterate(self, samples, checker, tree, best):
            q = super()._iterate(samples, checker, tree, best)
            if math.isfinite(best):
                n = tree.n
                over = tree.live[:n] & (tree.cost[:n] + tree.h[:n] > best * (1 + 1e-12))
                over[0] = False
                assert not over.any()
                seen.append(q)
            return q

    res = Checked(bn.load_scenario(name), n_nodes=400, seed=1, backend="numpy").plan()   # (its _iterate)
    assert res.success and len(seen) > 100 and res.stats["pruned"] > 0
