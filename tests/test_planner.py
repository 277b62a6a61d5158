"""IG-RRT* planner: verified paths, determinism, anytime behaviour, options."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import geometry
from belief_nlp.errors import ValidationError
from belief_nlp.planner import IGRRTStar, PlanResult, plan
from belief_nlp.planner.collision import CollisionChecker
from belief_nlp.scenario import scenario_from_dict


@pytest.fixture(scope="module")
def quad():
    return bn.load_scenario("quad")


@pytest.fixture(scope="module")
def quad_run(quad):
    return plan(quad, n_nodes=300, seed=3)


def _assert_verified(sc, res):
    assert res.success, res.message
    assert isinstance(res.path, bn.BeliefPath)
    rep = bn.verify(sc, res.path)
    assert rep.safe, rep.summary()
    assert res.verification["safe"]
    # the path ends inside the target and starts at the scenario's start
    assert np.allclose(res.path.x[0], sc.x0)
    assert np.min(geometry.containment_margins(res.path.x[-1], res.path.P[-1], sc.target.A, sc.target.b,
                                               sc.chi2)) >= 0


@pytest.mark.parametrize("name, n", [("quad", 300), ("paper-multi", 300), ("cube3d", 300)])
def test_paths_are_verified(name, n):
    sc = bn.load_scenario(name)
    res = plan(sc, n_nodes=n, seed=0)
    _assert_verified(sc, res)
    assert res.path.noise == sc.planner.get("noise", "per_metre")     # the scenario says which model
    assert res.path.meta["seed"] == 0 and res.path.meta["options"]["n_nodes"] == n


@pytest.mark.parametrize("kw", [dict(metric="wasserstein"), dict(metric="hellinger"), dict(noise="per_step"),
                                dict(steering="linear", goal_bias=0.0), dict(info_unit="bits")])
def test_metrics_noise_and_steering_give_verified_paths(quad, kw):
    res = plan(quad, n_nodes=300, seed=1, **kw)
    _assert_verified(quad, res)
    assert res.path.noise == kw.get("noise", "per_metre")
    if kw.get("noise") == "per_step":
        # one step per edge whatever its length: P_prior_k - P_{k-1} = W
        assert np.allclose(res.path.transition_noise, quad.W)


def test_cost_split_and_units(quad, quad_run):
    res = quad_run
    path = res.path
    assert res.cost == pytest.approx(res.travel + res.alpha * res.information, rel=1e-9)
    assert res.travel == pytest.approx(path.length, rel=1e-12)
    # entropy in nats is the path's own information, and the planner cost matches
    assert res.information == pytest.approx(path.information, rel=1e-6)
    assert res.cost == pytest.approx(path.planner_cost(res.alpha), rel=1e-6)
    # the authors' unit: length + alpha/2 (log2 det P_hat - log2 det P) = length + alpha nats / ln 2
    theirs = path.length + res.alpha * 0.5 * np.sum(np.log2(np.linalg.det(path.P_prior[1:]))
                                                    - np.log2(np.linalg.det(path.P[1:])))
    assert res.cost_in_authors_units() == pytest.approx(theirs, rel=1e-6)
    bits = plan(quad, n_nodes=150, seed=3, info_unit="bits")
    assert bits.cost == pytest.approx(bits.cost_in_authors_units(), rel=1e-9)
    assert bits.information == pytest.approx(bits.information_nats / math.log(2), rel=1e-12)


def test_same_seed_same_path(quad, quad_run):
    again = plan(quad, n_nodes=300, seed=3)
    assert again.path == quad_run.path
    assert np.array_equal(again.cost_history, quad_run.cost_history)
    assert np.array_equal(again.tree.x, quad_run.tree.x)
    other = plan(quad, n_nodes=300, seed=4)
    assert not np.array_equal(other.tree.x, quad_run.tree.x)


def test_anytime_history(quad_run):
    h = quad_run.cost_history
    assert h.shape == (quad_run.stats["nodes"],) == (300,)
    fin = np.isfinite(h)
    k = quad_run.first_solution_iteration
    assert k is not None and fin[k - 1] and not fin[: k - 1].any()
    assert np.all(np.diff(h[fin]) <= 0)                      # more nodes never worse
    assert h[-1] == quad_run.cost
    # a shorter run is a prefix of a longer one (nothing depends on the budget)
    short = plan(bn.load_scenario("quad"), n_nodes=200, seed=3)
    assert np.array_equal(short.cost_history, h[:200])


def test_tree_attributes(quad, quad_run):
    t = quad_run.tree
    n = len(t)
    assert t.x.shape == (n, 2) and t.P.shape == (n, 2, 2) and t.parent.shape == (n,) and t.cost.shape == (n,)
    assert t.parent[0] == -1 and t.cost[0] == 0 and np.all(t.parent[1:] >= 0) and np.all(t.parent < n)
    assert np.allclose(t.x[0], quad.x0)
    # walking up from any node reaches the root (a tree, no cycles)
    for v in range(0, n, 17):
        steps = 0
        while v != 0:
            v = t.parent[v]
            steps += 1
            assert steps < n
    # the cost-to-come of the path's last node is the result's cost
    goal = quad_run.path.meta["nodes"][-1]
    assert t.goal[goal] and t.cost[goal] == pytest.approx(quad_run.cost)


def test_branch_and_bound(quad):
    on = plan(quad, n_nodes=300, seed=5, branch_and_bound=True)
    off = plan(quad, n_nodes=300, seed=5, branch_and_bound=False)
    for res in (on, off):
        _assert_verified(quad, res)
    # Pruning starts with the first solution; until then the runs are the same run.
    k = on.first_solution_iteration
    assert k == off.first_solution_iteration
    assert np.array_equal(on.cost_history[:k], off.cost_history[:k])
    assert np.array_equal(on.tree.x[:k], off.tree.x[:k])
    # It never removes the best path, and every live node can still improve on it.
    t = on.tree
    assert t.live[on.path.meta["nodes"]].all()
    assert on.stats["pruned"] > 0 and off.stats["pruned"] == 0
    assert np.all(off.tree.live)
    # Pruned nodes leave the nearest/parent/rewiring searches, so later samples
    # differ and the final costs differ in general (pruning focuses the search;
    # the planner benchmark has the distribution over seeds). Both runs end at
    # a comparable cost.
    assert on.cost <= 1.5 * off.cost and off.cost <= 1.5 * on.cost
    # The bound is admissible and consistent: no kept node is hopeless, and the
    # ancestors of kept nodes are kept.
    n = len(t)
    live = np.flatnonzero(t.live)
    tree = IGRRTStar(quad)  # for the bound h
    h = np.array([tree._h(t.x[i], np.linalg.slogdet(t.P[i])[1]) for i in live])
    assert np.all(t.cost[live] + h <= on.cost * (1 + 1e-9))
    assert np.all(t.live[t.parent[live[1:]]])
    assert n == 300


def test_unreachable_target_fails_cleanly():
    sc = scenario_from_dict({
        "name": "walled", "alpha": 0.1,
        "start": {"x": [0.1, 0.5], "P": 1e-6},
        "noise": {"W": 2e-4, "W_rate": 1e-3},
        "domain": {"box": {"lower": [0, 0], "upper": [1, 1]}},
        "target": {"box": {"lower": [0.8, 0.4], "upper": [0.9, 0.5]}},
        "obstacles": [{"box": {"lower": [0.45, 0.0], "upper": [0.55, 0.5]}},
                      {"box": {"lower": [0.45, 0.5], "upper": [0.55, 1.0]}}],
    })
    res = plan(sc, n_nodes=150, seed=0)
    assert not res.success and res.path is None and math.isinf(res.cost)
    assert "no path" in res.message and "150 nodes" in res.message
    assert res.first_solution_iteration is None and np.all(np.isinf(res.cost_history))
    assert np.all(res.tree.x[:, 0] < 0.45)                    # nothing crossed the wall
    # a tiny attempt budget ends the run too, with the reason in the message
    res = plan(sc, n_nodes=10_000, seed=0, max_attempts=50)
    assert not res.success and "attempt limit" in res.message


@pytest.mark.parametrize("kw, field", [
    (dict(n_nodes=0), "n_nodes"), (dict(n_nodes=2.5), "n_nodes"), (dict(metric="foo"), "metric"),
    (dict(noise="bar"), "noise"), (dict(time_limit=-1.0), "time_limit"), (dict(time_limit=0), "time_limit"),
    (dict(eig_range=(1e-1, 1e-9)), "eig_range"), (dict(eig_range=(0.0, 1.0)), "eig_range"),
    (dict(eig_range="small"), "eig_range"), (dict(alpha=-1), "alpha"), (dict(max_radius=0), "max_radius"),
    (dict(goal_bias=1.0), "goal_bias"), (dict(seed=-3), "seed"), (dict(branch_and_bound="yes"), "branch_and_bound"),
    (dict(info_unit="bits", metric="hellinger"), "info_unit"), (dict(steering="curved"), "steering"),
    (dict(frobnicate=1), "frobnicate"),
])
def test_bad_options_name_the_option(quad, kw, field):
    with pytest.raises(ValidationError) as err:
        plan(quad, **kw)
    assert err.value.field == field
    assert field in str(err.value)


def test_options_from_scenario(quad):
    planner = IGRRTStar(quad, n_nodes=50)
    assert planner.options.max_radius == quad.planner["max_radius"] == 0.5
    assert planner.options.alpha == quad.alpha
    assert IGRRTStar(quad, max_radius=0.2, alpha=0.3).options.max_radius == 0.2
    with pytest.raises(ValidationError) as err:
        IGRRTStar(quad.with_options(planner={"max_radius": -1}))
    assert err.value.field == "max_radius"


def test_time_limit_and_convergence(quad):
    res = plan(quad, n_nodes=100_000, seed=0, time_limit=0.3)
    assert "time limit" in res.message and res.stats["nodes"] < 100_000
    assert res.timings["total"] < 5.0
    res = plan(quad, n_nodes=5000, seed=0, convergence_tol=1e-2, convergence_window=60)
    assert res.success and "converged" in res.message and res.stats["nodes"] < 5000
    h = res.cost_history
    assert h[-61] - h[-1] <= 1e-2 * h[-1]


def test_save_load_round_trip(tmp_path, quad_run):
    for suffix in (".json", ".npz"):
        f = quad_run.save(tmp_path / f"plan{suffix}")
        back = PlanResult.load(f)
        assert back.success and back.cost == quad_run.cost and back.path == quad_run.path
        assert np.array_equal(back.cost_history, quad_run.cost_history)
        assert np.array_equal(back.tree.parent, quad_run.tree.parent)
        assert np.array_equal(back.tree.P, quad_run.tree.P)
        assert back.first_solution_iteration == quad_run.first_solution_iteration
        assert back.options == quad_run.options and back.stats == quad_run.stats
    # a failed result (infinite cost, no path) round-trips too
    failed = plan(bn.load_scenario("quad"), n_nodes=5, seed=0)
    assert not failed.success
    back = PlanResult.load(failed.save(tmp_path / "failed.json"))
    assert back.path is None and math.isinf(back.cost) and not back.success
    with pytest.raises(ValidationError):
        quad_run.save(tmp_path / "plan.txt")


def test_logger_and_progress(quad, caplog, capsys):
    """Under pytest stderr is no terminal: progress comes as log lines, not a bar."""
    with caplog.at_level(logging.INFO, logger="belief_nlp"):
        plan(quad, n_nodes=120, seed=0, progress=True)
    assert any(r.name == "belief_nlp.planner" for r in caplog.records)
    assert any(r.name == "belief_nlp.progress" and "IG-RRT*" in r.getMessage() for r in caplog.records)
    assert "\r" not in capsys.readouterr().err


def _random_edges(sc, rng, n):
    lo, hi = sc.domain.vertices.min(0), sc.domain.vertices.max(0)
    d = sc.dim
    x0 = lo + (hi - lo) * rng.random((n, d))
    x1 = x0 + rng.normal(0, 0.15, (n, d))
    A = rng.normal(size=(n, d, d))
    P0 = (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(d)) * 10 ** rng.uniform(-6, -3, (n, 1, 1))
    W = 1e-3 * np.linalg.norm(x1 - x0, axis=1)[:, None, None] * np.eye(d)
    return x0, P0, x1, W


@pytest.mark.parametrize("name", ["paper-multi", "cube3d", "tutorial"])
def test_collision_layers_match_the_exact_check(name):
    """The closed-form certificates and witnesses decide exactly like Theorem 1."""
    sc = bn.load_scenario(name)
    checker = CollisionChecker(sc, safety_margin=1e-6)
    ps = geometry.PolytopeSet.build(sc.hazards)
    rng = np.random.default_rng(7)
    x0, P0, x1, W = _random_edges(sc, rng, 400)
    mine = checker.transitions_clear(x0, P0, x1, W)
    exact = geometry.transitions_clear(x0, P0, x1, W, ps, sc.chi2, margin=sc.chi2 * 1e-6).all(axis=1)
    assert np.array_equal(mine, exact)
    assert 0.1 < mine.mean() < 0.9                            # both outcomes exercised
    assert checker.stats["edges_exact"] < 400                 # and the cheap layers did work


def test_geodesic_steering_is_lossless(quad):
    planner = IGRRTStar(quad)
    rng = np.random.default_rng(0)
    for _ in range(50):
        xn, xs = rng.random(2), rng.random(2)
        Pn = np.diag(10 ** rng.uniform(-9, -2, 2))
        Ps = np.diag(10 ** rng.uniform(-9, -1, 2))
        t = rng.random()
        x, P = planner._steer(xn, Pn, xs, Ps, t)
        P_hat = Pn + np.linalg.norm(x - xn) * quad.W_rate
        assert bn.belief.is_lossless(P_hat, P, rtol=-1e-7)    # strictly below the prior
        assert np.allclose(x, xn + t * (xs - xn))


@pytest.mark.parametrize("metric", ["entropy", "wasserstein", "hellinger"])
@pytest.mark.parametrize("d", [2, 3])
def test_edge_metrics_match_belief_module(metric, d):
    """The batched closed-form kernels agree with belief.py's definitions."""
    from belief_nlp import belief
    from belief_nlp.planner.kernels import chol_factors
    from belief_nlp.planner.metrics import EdgeMetric

    rng = np.random.default_rng(d)
    n = 40
    A = rng.normal(size=(n, d, d))
    P = (A @ np.swapaxes(A, 1, 2) + 0.2 * np.eye(d)) * 1e-4
    w = rng.uniform(0.05, 0.5, n)
    W = 1e-3 * np.eye(d)
    B = rng.normal(size=(d, d))
    C = (B @ B.T + 0.2 * np.eye(d)) * 3e-5
    m = EdgeMetric(metric, alpha=0.1, info_unit="nats", W_edge=W)
    L, Linv, _, _ = chol_factors(C)
    P_hat = P + w[:, None, None] * W
    Cs = np.broadcast_to(C, P.shape)
    lossless, info = m.edges_to(P, w, C, L, Linv)
    assert np.array_equal(lossless, belief.is_lossless(P_hat, Cs, rtol=-1e-7))
    ref = {"entropy": lambda a, b: belief.information_cost(a, b),
           "wasserstein": lambda a, b: belief.wasserstein_distance(b, a),
           "hellinger": lambda a, b: belief.hellinger_distance(b, a)}[metric]
    assert np.allclose(info, ref(P_hat, Cs), rtol=1e-6, atol=1e-9)
    mm = belief.matrix_minimum(P_hat, Cs)
    assert np.allclose(m.nearest_info(P, w, C, Linv), ref(P_hat, mm), rtol=1e-6, atol=1e-9)
    # from one parent Q to every node (rewiring direction)
    Q = C * 5
    Ls = np.linalg.cholesky(P)
    lossless_r, info_r = m.edges_from(Q, w, P, Ls, np.linalg.inv(Ls))
    Q_hat = Q + w[:, None, None] * W
    assert np.array_equal(lossless_r, belief.is_lossless(Q_hat, P, rtol=-1e-7))
    assert np.allclose(info_r, ref(Q_hat, P), rtol=1e-6, atol=1e-9)
