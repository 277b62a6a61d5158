"""The planner's third-round fast paths give what the plain computations give.

Each fast path can be switched off (a module constant), and with it off the
planner runs the straightforward numpy computation of the earlier rounds:

* the 2-D sub-interval layers in Python floats
  (:mod:`belief_nlp.planner.refine_scalar`) decide every edge and count
  every statistic as the numpy rounds do, on random and grazing edges;
* the 2-D geodesic steering in Python floats is the generic steering bit
  for bit;
* the stacked edge-cost kernels (six products in one call) are the row
  kernels bit for bit;
* whole planner runs with every fast path on and off give identical trees
  (means, covariances, parents, costs) and statistics (but for the counts
  of the collision layers, whose depths differ), on paper-multi per step
  and per metre and on maps of a random family.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.families import generate
from belief_nlp.planner import collision
from belief_nlp.planner.collision import CollisionChecker

MARGIN = 1e-6


def _grazing_edges(sc, rng, n):
    """Transitions starting and ending near obstacle vertices with small
    covariances: the screen leaves many pairs open."""
    verts = np.concatenate([h.vertices for h in sc.hazards if h.vertices is not None])
    x0 = verts[rng.integers(len(verts), size=n)] + rng.normal(0, 0.03, (n, 2))
    x1 = x0 + rng.normal(0, 0.05, (n, 2))
    A = rng.normal(size=(n, 2, 2))
    P0 = (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(2)) * 10 ** rng.uniform(-7, -4, (n, 1, 1))
    W = np.broadcast_to(sc.W, (n, 2, 2)).copy()
    return x0, P0, x1, W


def _switched_off(monkeypatch):
    """The fast paths of this round off: the plain computations."""
    from belief_nlp.planner.iteration import IterationMixin

    monkeypatch.setattr(collision, "_SCALAR_PAIRS", -1)
    monkeypatch.setattr(IterationMixin, "_steer2", IterationMixin._steer_generic)


@pytest.mark.parametrize("name", ["paper-multi", "tutorial"])
@pytest.mark.parametrize("size", [1, 3, 12, 40])
def test_scalar_sub_intervals_are_the_numpy_rounds(name, size, monkeypatch):
    sc = bn.load_scenario(name)
    monkeypatch.setattr(collision, "_SCALAR_DEPTH", collision._DEPTH2)    # the same layers
    rng = np.random.default_rng(size)
    batches = [_grazing_edges(sc, rng, size) for _ in range(30)]
    monkeypatch.setattr(collision, "_SCALAR_PAIRS", 10 ** 6)
    fast = CollisionChecker(sc, MARGIN)
    got = [fast.transitions_clear(*b) for b in batches]
    monkeypatch.setattr(collision, "_SCALAR_PAIRS", -1)
    plain = CollisionChecker(sc, MARGIN)
    want = [plain.transitions_clear(*b) for b in batches]
    assert all(np.array_equal(g, w) for g, w in zip(got, want))
    assert fast.stats == plain.stats
    assert plain.stats["edges_refined"] > 0


def test_scalar_sub_intervals_fall_back_on_singular_covariances(monkeypatch):
    """A covariance that is not positive definite (numpy: NaN and inf,
    Python: an exception) goes to the numpy layers: the same verdict."""
    from belief_nlp.planner import refine_scalar

    sc = bn.load_scenario("paper-multi")
    x0, P0, x1, W = _grazing_edges(sc, np.random.default_rng(0), 8)
    P0[:] = np.diag([1e-6, 0.0])
    W[:] = 0.0
    m = CollisionChecker(sc, MARGIN).n_obs
    e, j = np.repeat(np.arange(8), m), np.tile(np.arange(m), 8)
    refused = []
    monkeypatch.setattr(collision, "refine_pairs", lambda *a: refused.append(refine_scalar.refine_pairs(*a)))
    with np.errstate(all="ignore"):
        monkeypatch.setattr(collision, "_SCALAR_PAIRS", 10 ** 6)
        got = CollisionChecker(sc, MARGIN)._refine(x0, x1, P0, W, e, j)
        monkeypatch.setattr(collision, "_SCALAR_PAIRS", -1)
        want = CollisionChecker(sc, MARGIN)._refine(x0, x1, P0, W, e, j)
    assert refused == [None]
    assert np.array_equal(got, want)


@pytest.mark.parametrize("noise", ["per_step", "per_metre"])
def test_steer2_is_the_generic_steering_bit_for_bit(noise, monkeypatch):
    from belief_nlp.planner import IGRRTStar

    pl = IGRRTStar(bn.load_scenario("paper-multi"), noise=noise)
    rng = np.random.default_rng(4)
    cases = []
    for _ in range(300):
        A, B = rng.normal(size=(2, 2, 2)) * 10 ** rng.uniform(-3, -1, (2, 1, 1))
        cases.append((rng.random(2), A @ A.T + 1e-8 * np.eye(2), rng.random(2), B @ B.T + 1e-8 * np.eye(2),
                      float(rng.uniform(0.05, 1.0))))
    cases.append((np.zeros(2), np.zeros((2, 2)), np.zeros(2), np.eye(2) * 1e-4, 0.5))   # singular prior (per metre)
    fast = [pl._steer(*c) for c in cases]
    plain = [pl._steer_generic(*c) for c in cases]
    for (xf, Pf), (xp, Pp) in zip(fast, plain):
        assert np.array_equal(xf, xp) and np.array_equal(Pf, Pp)


@pytest.mark.parametrize("metric", ["entropy", "hellinger"])
def test_stacked_kernels_are_the_row_kernels_bit_for_bit(metric):
    from belief_nlp.planner.kernels import ROWS_S
    from belief_nlp.planner.metrics import EdgeMetric

    rng = np.random.default_rng(6)
    m = EdgeMetric(metric, 0.7, "nats", np.eye(2) * 2e-4)
    n = 400
    s11, s22 = 10 ** rng.uniform(-7, -2, (2, n))
    s12 = rng.uniform(-0.9, 0.9, n) * np.sqrt(s11 * s22)
    t11, t22 = 10 ** rng.uniform(0, 4, (2, n))
    t21 = rng.normal(size=n) * 10 ** rng.uniform(-300, 4, n)      # down to tiny off-diagonals
    t21[:5] = 0.0
    S = np.stack([s11, s12, s22, t11, t21, t22])
    for got, want in zip(m.edges2_rows(S), m.edges2(*S)):
        assert np.array_equal(got, want)
    S6 = S[:3].take(ROWS_S, axis=0)
    for i in range(0, n, 37):
        t = (float(t11[i]), float(t21[i]), float(t22[i]))
        assert np.array_equal(m.nearest_info2_rows(S6, *t), m.nearest_info2(s11, s12, s22, *t))


def _fingerprint(res) -> str:
    h = hashlib.sha1()
    for arr in (res.tree.x, res.tree.P, res.tree.parent, res.tree.cost):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("case", ["paper-multi", "paper-multi-per-metre", "random-polygons@2",
                                  "random-polygons@7", "corridor@1"])
def test_fast_paths_give_the_same_trees(case, monkeypatch):
    if "@" in case:
        fam, s = case.split("@")
        sc, kw = generate(fam, int(s)), {}
    else:
        sc = bn.load_scenario("paper-multi")
        kw = {"noise": "per_metre"} if case.endswith("per-metre") else {}
    kw["backend"] = "numpy"          # the numpy attempt's fast paths (the compiled one has its own tests)
    fast = [bn.plan(sc, n_nodes=300, seed=seed, **kw) for seed in (0, 1)]
    _switched_off(monkeypatch)
    plain = [bn.plan(sc, n_nodes=300, seed=seed, **kw) for seed in (0, 1)]
    for f, p in zip(fast, plain):
        assert _fingerprint(f) == _fingerprint(p)
        assert ({k: v for k, v in f.stats.items() if not k.startswith("collision")}
                == {k: v for k, v in p.stats.items() if not k.startswith("collision")})
