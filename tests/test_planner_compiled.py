"""The compiled (numba) attempt of the planner (``backend="numba"``).

* its collision verdicts are the numpy checker's on random, grazing and
  recorded edge batches (paper-multi, tutorial, random-polygons maps), and
  every verdict agrees with the exact minimum;
* its kernels (edge costs, steering, shrink exponent, target test, cost to
  go) are the numpy ones to rounding;
* its plans pass the independent verification, every edge of its trees is
  clear for the numpy checker, and its costs are those of the numpy backend
  (same success, median within a generous bound);
* the ``backend`` option is validated.
"""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.families import generate
from belief_nlp.planner import IGRRTStar, compiled
from belief_nlp.planner.collision import CollisionChecker

pytest.importorskip("numba")

from belief_nlp.planner.compiled import attempt as A  # noqa: E402
from belief_nlp.planner.compiled import collide, linalg  # noqa: E402
from belief_nlp.planner.compiled.driver import hazard_arrays, transitions_clear  # noqa: E402

MARGIN = 1e-6
SCENARIOS = ["paper-multi", "tutorial", "random-polygons@2", "random-polygons@5", "random-polygons@9"]


def _scenario(name):
    if "@" in name:
        fam, s = name.split("@")
        return generate(fam, int(s))
    return bn.load_scenario(name)


def _edges(sc, rng, n, grazing):
    """Random transitions; ``grazing``: starting and ending near obstacle
    vertices with small covariances (the cheap layers leave pairs open)."""
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    if grazing:
        verts = np.concatenate([h.vertices for h in sc.hazards if h.vertices is not None])
        x0 = verts[rng.integers(len(verts), size=n)] + rng.normal(0, 0.03, (n, 2))
        x1 = x0 + rng.normal(0, 0.05, (n, 2))
        scale = 10 ** rng.uniform(-7, -4, (n, 1, 1))
    else:
        x0 = lo + (hi - lo) * rng.random((n, 2))
        x1 = x0 + rng.normal(0, 0.15, (n, 2))
        scale = 10 ** rng.uniform(-6, -3, (n, 1, 1))
    B = rng.normal(size=(n, 2, 2))
    P0 = (B @ np.swapaxes(B, 1, 2) + 0.1 * np.eye(2)) * scale
    W = np.broadcast_to(sc.W, (n, 2, 2)) * rng.uniform(0.1, 3.0, (n, 1, 1))
    return x0, P0, x1, np.ascontiguousarray(W)


# ------------------------------------------------------------ collision verdicts
@pytest.mark.parametrize("name", SCENARIOS)
def test_verdicts_are_the_numpy_checkers(name):
    sc = _scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    rng = np.random.default_rng(3)
    n_edges = n_clear = 0
    for grazing in (False, True):
        for size in (1, 5, 40, 200):
            x0, P0, x1, W = _edges(sc, rng, size, grazing)
            want = checker.transitions_clear(x0, P0, x1, W)
            got = transitions_clear(checker, x0, P0, x1, W)
            assert np.array_equal(got, want)
            n_edges += size
            n_clear += int(got.sum())
    assert 0 < n_clear < n_edges


def test_verdicts_agree_with_the_exact_minimum():
    """Clear only where the exact minimum clears chi2, blocked only where it
    is below the checker's threshold (grazing edges on a random map)."""
    from belief_nlp import geometry

    sc = _scenario("random-polygons@5")
    checker = CollisionChecker(sc, MARGIN)
    x0, P0, x1, W = _edges(sc, np.random.default_rng(8), 400, True)
    got = transitions_clear(checker, x0, P0, x1, W)
    hazards = [h for h in sc.hazards if h.A.shape[0] > 1] + [h for h in sc.hazards if h.A.shape[0] == 1]
    lower, upper = geometry.transition_bounds(x0, P0, x1, W, geometry.PolytopeSet.build(hazards))
    assert np.all(lower[got].min(axis=1) >= sc.chi2)
    assert np.all(upper[~got].min(axis=1) < checker.thr)
    assert 0 < got.sum() < got.size


def _vertex_grazers(sc, thr, rel):
    """Transitions passing an obstacle vertex at a Mahalanobis distance of
    sqrt(thr (1 + rel)) (min over s): no face certifies them and the
    sub-interval layers cannot decide them, so the exact minimiser does."""
    x0, x1, P0, W = [], [], [], []
    sig2 = 1e-6
    for h in sc.hazards:
        if h.A.shape[0] < 3:
            continue
        V = h.vertices
        c = V.mean(axis=0)
        for v in V:
            n = (v - c) / np.linalg.norm(v - c)
            t = np.array([-n[1], n[0]])
            L = 0.2
            s = np.linspace(0.0, 1.0, 200001)
            # d2(s) = (r^2 + ((s - 1/2) L)^2) / (sig2 (1 + s)): r from its minimum
            g = ((s - 0.5) * L) ** 2 / (1 + s)
            f = 1.0 / (1 + s)
            lo, hi = 0.0, 1.0
            for _ in range(80):       # bisection on r^2: min_s (r^2 f + g) / sig2 = thr (1 + rel)
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if np.min(mid * f + g) / sig2 < thr * (1 + rel) else (lo, mid)
            r = np.sqrt(hi)
            x0.append(v + r * n - 0.5 * L * t)
            x1.append(v + r * n + 0.5 * L * t)
            P0.append(sig2 * np.eye(2))
            W.append(sig2 * np.eye(2))
    return np.array(x0), np.array(P0), np.array(x1), np.array(W)


@pytest.mark.parametrize("rel", [1e-6, -1e-6])
def test_undecided_edges_go_to_the_exact_minimiser(rel):
    sc = bn.load_scenario("paper-multi")
    checker = CollisionChecker(sc, MARGIN)
    x0, P0, x1, W = _vertex_grazers(sc, checker.thr, rel)
    F, nf, n_obs, VE = hazard_arrays(checker)
    status = np.zeros(len(x0), dtype=np.int64)
    collide.decide_batch(x0, P0, x1, W, F, nf, n_obs, VE, checker.thr, checker.thr_witness, 10,
                         np.zeros((14, 10)), np.zeros(nf.size, dtype=bool), status)
    assert np.count_nonzero(status == collide.EXACT) >= len(x0) // 2
    got = transitions_clear(checker, x0, P0, x1, W)
    assert np.array_equal(got, checker.transitions_clear(x0, P0, x1, W))
    # (some pass flat vertices, where an edge's ellipses come closer than at the vertex)
    assert got.sum() > len(got) // 2 if rel > 0 else not got.any()


def test_plans_with_the_exact_fallback_everywhere(monkeypatch):
    """With no sub-interval halving every open pair goes to the exact
    minimiser (parents before and after a clear one, rewiring edges): the
    plans still verify and every tree edge is clear."""
    from belief_nlp.planner.compiled import driver

    monkeypatch.setattr(driver, "_DEPTH", 0)
    sc = _scenario("random-polygons@2")
    for seed in (0, 3):
        res = bn.plan(sc, n_nodes=200, seed=seed, backend="numba")
        assert res.stats["collision_edges_exact"] >= 5
        assert res.success and bn.verify(sc, res.path).safe
        assert _tree_edges_clear(res, sc, sc.planner.get("noise", "per_metre")).all()


def _recorded_batches(sc, **kw):
    """The collision batches of a numpy-backend run."""
    batches = []
    orig = CollisionChecker.transitions_clear

    def record(self, x0, P0, x1, W_e, ordered=0):
        batches.append((self, x0.copy(), P0.copy(), x1.copy(), W_e.copy()))
        return orig(self, x0, P0, x1, W_e, ordered)

    CollisionChecker.transitions_clear = record
    try:
        bn.plan(sc, n_nodes=150, seed=2, backend="numpy", **kw)
    finally:
        CollisionChecker.transitions_clear = orig
    return batches


@pytest.mark.parametrize("name, noise", [("paper-multi", "per_step"), ("paper-multi", "per_metre"),
                                         ("random-polygons@2", None)])
def test_recorded_batches_get_the_numpy_verdicts(name, noise):
    sc = _scenario(name)
    batches = _recorded_batches(sc, **({"noise": noise} if noise else {}))
    assert len(batches) > 50
    for checker, x0, P0, x1, W in batches:
        assert np.array_equal(transitions_clear(checker, x0, P0, x1, W), checker.transitions_clear(x0, P0, x1, W))


def test_hazard_arrays_drop_the_screens_padding():
    checker = CollisionChecker(bn.load_scenario("paper-multi"), MARGIN)
    F, nf, n_obs, VE = hazard_arrays(checker)
    assert nf.tolist() == [4, 3, 3, 4, 4, 4, 1, 1, 1, 1] and n_obs == 6 and VE.shape[:2] == (6, 4)


# ------------------------------------------------------------------ kernels
def _spd(rng, lo=-7, hi=-2):
    B = rng.normal(size=(2, 2))
    return (B @ B.T + 0.05 * np.eye(2)) * 10 ** rng.uniform(lo, hi)


@pytest.mark.parametrize("metric", ["entropy", "hellinger"])
def test_edge_costs_are_the_numpy_kernels(metric):
    from belief_nlp.planner.metrics import EdgeMetric

    m = EdgeMetric(metric, 0.7, "nats", np.eye(2) * 2e-4)
    rng = np.random.default_rng(6)
    n = 300
    s11, s22 = 10 ** rng.uniform(-7, -2, (2, n))
    s12 = rng.uniform(-0.9, 0.9, n) * np.sqrt(s11 * s22)
    t11, t22 = 10 ** rng.uniform(0, 4, (2, n))
    t21 = rng.normal(size=n) * 10 ** rng.uniform(-20, 4, n)
    lossless, info = m.edges2(s11, s12, s22, t11, t21, t22)
    near = m.nearest_info2(s11, s12, s22, t11, t21, t22)
    code = linalg.ENTROPY if metric == "entropy" else linalg.HELLINGER
    for i in range(n):
        small, big = linalg.congruence_pair(s11[i], s12[i], s22[i], t11[i], t21[i], t22[i])
        assert (small >= linalg.LOSSLESS_MIN) == lossless[i]
        assert linalg.info_pair(small, big, 1e-300, code) == pytest.approx(info[i], rel=1e-12, abs=1e-300)
        assert linalg.info_pair(small, big, 1.0, code) == pytest.approx(near[i], rel=1e-12, abs=1e-300)


def test_candidate_order_is_numpys_stable_argsort():
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 3, 7, 16, 33, 200):
        for key in (rng.random(n), rng.integers(0, 4, n).astype(float)):
            order, tmp = np.zeros(n + 2, dtype=np.int64), np.zeros(n + 2, dtype=np.int64)
            A.stable_order(key, n, order, tmp)
            assert np.array_equal(order[:n], np.argsort(key, kind="stable"))


@pytest.mark.parametrize("noise", ["per_step", "per_metre"])
@pytest.mark.parametrize("steering", ["geodesic", "linear"])
def test_steering_is_the_numpy_steering(noise, steering):
    pl = IGRRTStar(bn.load_scenario("paper-multi"), noise=noise, steering=steering, backend="numpy")
    W = pl.W_edge
    rng = np.random.default_rng(4)
    for _ in range(200):
        xn, xs = rng.random(2), rng.random(2)
        Pn, Ps = _spd(rng), _spd(rng)
        t = float(rng.uniform(0.05, 1.0))
        x, P = pl._steer(xn, Pn, xs, Ps, t)
        got = linalg.steer(xn[0], xn[1], Pn[0, 0], Pn[0, 1], Pn[1, 1], xs[0], xs[1], Ps[0, 0], Ps[0, 1], Ps[1, 1],
                           t, W[0, 0], W[0, 1], W[1, 1], noise == "per_metre", steering == "geodesic")
        np.testing.assert_allclose(got[:2], x, rtol=1e-12, atol=0)
        np.testing.assert_allclose(got[2:], [P[0, 0], P[0, 1], P[1, 1]], rtol=1e-9, atol=1e-12 * abs(P).max())


@pytest.mark.parametrize("name", ["paper-multi", "random-polygons@2"])
def test_shrink_target_and_cost_to_go_are_the_numpy_ones(name):
    sc = _scenario(name)
    checker = CollisionChecker(sc, MARGIN)
    F, nf, n_obs, VE = hazard_arrays(checker)
    pl = IGRRTStar(sc, backend="numpy")
    T = np.column_stack([sc.target.A, sc.target.b])
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    tlo, thi = sc.target.vertices.min(0), sc.target.vertices.max(0)
    rng = np.random.default_rng(5)
    shrunk = 0
    for i in range(400):
        x = (tlo + (thi - tlo) * rng.random(2)) if i % 4 == 0 else lo + (hi - lo) * rng.random(2)
        P = _spd(rng, -6, -1)
        k = checker.shrink_exponent(x, P)
        got = collide.shrink_exponent(x[0], x[1], P[0, 0], P[0, 1], P[1, 1], F, nf, n_obs, VE, checker.thr)
        assert got == (-1 if k is None else k)
        shrunk += bool(k)
        assert collide.in_target(x[0], x[1], P[0, 0], P[0, 1], P[1, 1], T, checker.thr_target) == \
            checker.in_target(x, P)
        logdet = float(np.linalg.slogdet(P)[1])
        assert A.cost_to_go(x[0], x[1], logdet, T, pl.metric.weight, True, pl._logdet_max) == \
            pytest.approx(pl._h(x, logdet), rel=1e-12, abs=1e-15)
    assert shrunk > 20


# -------------------------------------------------------------------- plans
def _tree_edges_clear(res, sc, noise):
    """Every edge of the tree, decided by the numpy checker."""
    t = res.tree
    v = np.arange(1, t.parent.size)
    p = t.parent[v]
    W = sc.W_rate if noise == "per_metre" else sc.W
    w = np.linalg.norm(t.x[v] - t.x[p], axis=1) if noise == "per_metre" else np.ones(v.size)
    checker = CollisionChecker(sc, MARGIN)
    return checker.transitions_clear(t.x[p], t.P[p], t.x[v], w[:, None, None] * W)


@pytest.mark.parametrize("name, noise", [("paper-multi", "per_step"), ("paper-multi", "per_metre"),
                                         ("random-polygons@2", "per_metre"), ("tutorial", "per_metre")])
def test_numba_plans_verify_and_their_edges_are_clear(name, noise):
    sc = _scenario(name)
    for seed in (0, 1):
        res = bn.plan(sc, n_nodes=300, seed=seed, noise=noise, backend="numba")
        assert res.stats["backend"] == "numba"
        assert res.success and bn.verify(sc, res.path).safe
        assert _tree_edges_clear(res, sc, noise).all()


def test_numba_costs_are_the_numpy_costs():
    """Same success and a median best cost within 5 % (the trees part at
    the first tie that rounding decides; at N = 2000 over 20 seeds the cost
    quartiles agree within 3 %, docs/planner.md)."""
    sc = bn.load_scenario("paper-multi")
    costs = {}
    for backend in ("numpy", "numba"):
        runs = [bn.plan(sc, n_nodes=400, seed=s, backend=backend) for s in range(4)]
        assert all(r.success for r in runs)
        costs[backend] = np.median([r.cost for r in runs])
    assert abs(costs["numba"] - costs["numpy"]) <= 0.05 * costs["numpy"]


def test_numba_stats_have_the_numpy_keys():
    sc = bn.load_scenario("paper-multi")
    a = bn.plan(sc, n_nodes=100, seed=0, backend="numpy")
    b = bn.plan(sc, n_nodes=100, seed=0, backend="numba")
    assert set(a.stats) == set(b.stats) and a.stats["backend"] == "numpy"
    assert b.stats["attempts"] >= 100 and b.stats["collision_edges"] > 0


# --------------------------------------------------------------- the option
def test_backend_option_is_validated(monkeypatch):
    quad, cube = bn.load_scenario("quad"), bn.load_scenario("cube3d")
    with pytest.raises(ValidationError, match="backend"):
        IGRRTStar(quad, backend="fortran")
    with pytest.raises(ValidationError, match="backend.*2-D"):
        IGRRTStar(cube, backend="numba")
    with pytest.raises(ValidationError, match="backend.*wasserstein"):
        IGRRTStar(quad, backend="numba", metric="wasserstein")
    assert IGRRTStar(quad).backend == "numba"                      # the default, auto, with numba installed
    assert IGRRTStar(quad, backend="numpy").backend == "numpy"
    assert IGRRTStar(cube, backend="auto").backend == "numpy"
    assert IGRRTStar(quad, metric="wasserstein", backend="auto").backend == "numpy"
    assert IGRRTStar(quad, backend="auto").backend == "numba"
    assert IGRRTStar(quad.with_options(planner={"backend": "numba"})).backend == "numba"   # a scenario's table
    monkeypatch.setattr(compiled, "installed", lambda: False)
    monkeypatch.setattr(compiled, "available", lambda: False)
    with pytest.raises(ValidationError, match=r"backend.*belief-nlp\[fast\]"):
        IGRRTStar(quad, backend="numba")
    assert IGRRTStar(quad, backend="auto").backend == "numpy"
    assert IGRRTStar(quad).backend == "numpy"                      # without numba, the default plans in numpy


def test_cli_backend_option(tmp_path, capsys):
    """``belief-nlp plan --backend``: the plan records the backend it ran;
    a bad value is one line on stderr and exit 2."""
    from belief_nlp.cli import main
    from belief_nlp.planner import PlanResult

    for backend in ("numpy", "numba"):
        code = main(["plan", "quad", "--nodes", "150", "--alpha", "0.2", "--backend", backend, "--out", str(tmp_path / backend), "-q"])
        assert code == 0
        assert PlanResult.load(tmp_path / backend / "plan.json").stats["backend"] == backend
    capsys.readouterr()
    assert main(["plan", "quad", "--backend", "fortran", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "backend" in err[0]


def test_a_cold_cache_is_announced(monkeypatch, tmp_path, capsys):
    """The first numba plan of a machine compiles for seconds: the CLI says so
    (the library logs it at INFO); a warm cache, numpy or 3-D say nothing."""
    from belief_nlp.cli import main

    monkeypatch.setattr(compiled, "cache_is_warm", lambda: False)
    assert compiled.cold_compile_note("auto", 2, "entropy") == compiled.COLD_NOTE
    assert compiled.cold_compile_note("numpy", 2, "entropy") is None
    assert compiled.cold_compile_note("auto", 3, "entropy") is None
    assert compiled.cold_compile_note("numba", 3, "entropy") is None       # the planner reports that one
    assert main(["plan", "quad", "--nodes", "150", "--alpha", "0.2", "--out", str(tmp_path)]) == 0
    assert "compiling the numba attempt" in capsys.readouterr().err
    monkeypatch.setattr(compiled, "cache_is_warm", lambda: True)
    assert compiled.cold_compile_note("auto", 2, "entropy") is None
    assert main(["plan", "quad", "--nodes", "150", "--alpha", "0.2", "--out", str(tmp_path)]) == 0
    assert "compiling" not in capsys.readouterr().err


def test_loading_the_compiled_attempt_is_not_planning_time(monkeypatch):
    """Compiling or loading the numba attempt happens before the planner's
    clock: a slow load (as a cold cache's 12 s) neither eats the time limit
    nor shows in total / cpu / the anytime trace; it is timings["compile"]."""
    import time as _time

    from belief_nlp.planner.compiled import driver

    real = driver.CompiledAttempt.warm_up

    def slow(self, tree, sample):
        _time.sleep(1.5)                      # a cold cache, in small
        return real(self, tree, sample) + 1.5

    monkeypatch.setattr(driver.CompiledAttempt, "warm_up", slow)
    sc = bn.load_scenario("paper-multi")
    res = bn.plan(sc, n_nodes=300, seed=1, time_limit=1.0, backend="numba")
    assert res.timings["compile"] >= 1.5
    assert res.stats["attempts"] > 50                      # the limit was not spent before the first attempt
    assert res.timings["total"] < 1.5 + 1.0 and all(t < 1.5 for t, _ in res.cost_trace)
    # the warm-up attempt leaves no trace: the same tree as a run whose warm-up is skipped
    a = bn.plan(sc, n_nodes=300, seed=1, backend="numba")
    monkeypatch.setattr(driver.CompiledAttempt, "warm_up", lambda self, tree, sample: 0.0)
    b = bn.plan(sc, n_nodes=300, seed=1, backend="numba")
    assert a.cost == b.cost and a.stats["attempts"] == b.stats["attempts"]
    assert np.array_equal(a.tree.x, b.tree.x) and np.array_equal(a.tree.parent, b.tree.parent)


def test_a_numba_that_does_not_import_leaves_auto_on_numpy(monkeypatch, caplog):
    """numba installed but not importable (say, a NumPy newer than it
    supports): "auto" plans in numpy with one warning, "numba" names the
    field; nothing crashes."""
    import builtins

    real_import = builtins.__import__

    def broken(name, *args, **kwargs):                    # what an unsupported NumPy makes numba do
        if name == "numba":
            raise ImportError("Numba needs NumPy 2.3 or less. Got NumPy 9.9.")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", broken)
    compiled.available.cache_clear()
    try:
        with caplog.at_level("WARNING", logger="belief_nlp.planner"):
            assert not compiled.available()
        assert "does not import" in caplog.text
        quad = bn.load_scenario("quad")
        assert IGRRTStar(quad).backend == "numpy"
        with pytest.raises(ValidationError, match="backend.*does not import"):
            IGRRTStar(quad, backend="numba")
    finally:
        monkeypatch.undo()
        compiled.available.cache_clear()
    assert compiled.available()


def test_a_changed_source_drops_numbas_cache(tmp_path, monkeypatch):
    """numba keys a cached function on its own file only; an edit in a file it
    calls (or whose constants it compiled in) must drop the cached machine
    code, and an unchanged tree must keep it."""
    from belief_nlp.planner.compiled import cache

    pkg = tmp_path / "planner"
    here = pkg / "compiled"
    (here / "__pycache__").mkdir(parents=True)
    (pkg / "__pycache__").mkdir()
    src = [here / "collide.py", pkg / "refine_scalar.py"]
    for f in src:
        f.write_text("x = 1\n")
    monkeypatch.setattr(cache, "_HERE", here)
    monkeypatch.setattr(cache, "_SOURCES", src)

    def cached():
        return sorted(p.name for d in (here, pkg) for p in (d / "__pycache__").glob("*.nb[ic]"))

    def compile_all():
        for name in ("attempt.attempt-1.py311.nbi", "attempt.attempt-1.py311.1.nbc"):
            (here / "__pycache__" / name).write_text("")
        (pkg / "__pycache__" / "refine_scalar._factor-9.py311.nbi").write_text("")

    compile_all()
    cache.drop_stale_cache()                     # no stamp yet: the cache is of unknown sources
    assert cached() == []
    compile_all()
    cache.drop_stale_cache()                     # same sources: kept
    assert len(cached()) == 3
    src[1].write_text("x = 2\n")                 # a callee edited
    cache.drop_stale_cache()
    assert cached() == []
