"""The CCP smoother: monotone, always safe, tight at the end, honest on failure."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import InfeasibleStartError, ValidationError
from belief_nlp.geometry import PolytopeSet, transition_clearances
from belief_nlp.methods.ccp import _solve, compiled_step, initial_rho
from belief_nlp.model import BeliefModel, terms
from belief_nlp.model.doc import tangent

from conftest import densify, paper_multi_path_pair


def _cube3d_path():
    sc = bn.load_scenario("cube3d")
    x = densify(np.array([sc.x0, [0.2, 0.8, 0.2], [0.6, 0.85, 0.5], [0.82, 0.82, 0.82]]), 3)
    K = x.shape[0] - 1
    S = np.broadcast_to(1e4 * np.eye(3), (K, 3, 3))
    return sc, bn.BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)


@pytest.fixture(scope="module")
def paper_run():
    sc, path = paper_multi_path_pair()
    res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=40, keep_iterates=True)
    return sc, path, res


@pytest.fixture(scope="module")
def cube_run():
    sc, path = _cube3d_path()
    return sc, path, bn.smooth(sc, path, method="ccp", max_iter=40, keep_iterates=True)


@pytest.mark.parametrize("run", ["paper_run", "cube_run"])
def test_cost_falls_monotonically_and_below_the_start(run, request):
    sc, path, res = request.getfixturevalue(run)
    costs = np.array([h.cost for h in res.history if h.accepted])
    assert costs.size >= 3
    assert np.all(np.diff(costs) <= 1e-9 * np.abs(costs[:-1])), costs
    assert res.cost < 0.9 * res.initial_cost
    assert res.cost == pytest.approx(costs[-1])
    # the reported cost is the paper's objective of the returned path
    assert res.cost == pytest.approx(res.path.steering_cost(res.alpha), rel=1e-9)


@pytest.mark.parametrize("run", ["paper_run", "cube_run"])
def test_every_iterate_and_the_result_pass_independent_verification(run, request):
    sc, path, res = request.getfixturevalue(run)
    assert res.success and res.status == "converged"
    assert res.safe
    assert len(res.iterates) == sum(h.accepted for h in res.history)
    for p in res.iterates:
        assert bn.verify(sc, p).safe
    # and the exact continuous-time clearance of the result (a second method)
    hz = PolytopeSet.build(sc.hazards)
    p = res.path
    assert np.min(transition_clearances(p.x[:-1], p.P[:-1], p.x[1:], p.transition_noise, hz, sc.chi2)) >= 0


def test_known_converged_value_paper_multi_alpha1(paper_run):
    # numerics.md: hand-made start, K = 20, alpha = 1 converged at 2.3128
    _, _, res = paper_run
    assert res.cost == pytest.approx(2.3128, rel=2e-3)


@pytest.mark.parametrize("run", ["paper_run", "cube_run"])
def test_kalman_relaxation_is_tight_at_the_end(run, request):
    """Lemma 2: at the optimum Q_k^-1 = (Q_{k-1} + S_{k-1})^-1 + W; checked on the
    solver's raw Q (before the library re-derives the priors)."""
    _, _, res = request.getfixturevalue(run)
    assert res.history[-1].kalman_gap < 1e-3
    # and the returned path is Kalman-consistent with the per-step noise model
    p = res.path
    assert np.allclose(p.P_prior[1:], p.P[:-1] + res.path.transition_noise)


def test_target_containment_uses_the_corrected_sign(paper_run):
    """C4: [[b - a^T x_K, 1], [1, gamma C]] >= 0. With the printed top-left
    -b + a^T x_K the final mean would have to leave the target."""
    sc, _, res = paper_run
    p = res.path
    T = sc.target
    slack = T.b - T.A @ p.x[-1]
    assert np.all(slack > 0)                       # mean strictly inside
    gamma = 1 / np.sqrt(sc.chi2)
    C = 1 / np.sqrt(np.einsum("fi,ij,fj->f", T.A, p.P[-1], T.A))
    for s_n, c_n in zip(slack, C):
        corrected = np.array([[s_n, 1.0], [1.0, gamma * c_n]])
        printed = np.array([[-s_n, 1.0], [1.0, gamma * c_n]])
        assert np.linalg.eigvalsh(corrected)[0] >= -1e-9
        assert np.linalg.eigvalsh(printed)[0] < 0
    # and the CCP step's target cones are exactly this matrix at the current point
    model = BeliefModel(sc, p.K, res.alpha)
    ws = bn.warm_start(sc, p)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    form = model.convex_form
    one = np.ones((p.K, model.data.J))
    fam = next(f for f in form.families if f.name == "target_face")
    e = np.asarray(ca.Function("e", [form.z, form.p], [fam.expr])(form.layout.point_vector(z),
                                                                   form.layout.params(z, one, one)))
    M = e.reshape(fam.batch, 2, 2)
    y = (T.b - T.A @ ws.path.x[-1]) / model.data.sigma
    np.testing.assert_allclose(M[:, 0, 0], y, rtol=1e-9)
    assert np.min(np.linalg.eigvalsh(M)) >= -1e-9


def _first_step(sc, path, alpha):
    """The first CCP step at the warm start of ``path``, as the method builds
    it; returns (compiled step, point, objective of the convex form at z)."""
    ws = bn.warm_start(sc, path)
    model = BeliefModel(sc, ws.K, alpha)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    step, _, _ = compiled_step(model)
    rho = initial_rho(model, z)
    step.set_point(z, rho, rho)
    form = model.convex_form
    f = ca.Function("f", [form.z, form.p], [form.objective])
    pv = form.layout.params(z, rho, rho)
    return step, model, z, lambda v: float(f(v, pv))


def test_current_point_is_feasible_for_its_subproblem(paper_run):
    """CCP's premise: the linearisation point is feasible for the convex step
    (test_model checks every cone), so the step's optimum is no worse."""
    sc, path, _ = paper_run
    step, model, z, f = _first_step(sc, path, 1.0)
    status, sol, _, _ = _solve(step, "CLARABEL", {})          # Clarabel's own defaults
    assert status in ("optimal", "optimal_inaccurate") and sol is not None
    assert f(sol) <= f(step.layout.point_vector(z)) + 1e-8


def test_a_second_conic_solver_agrees_on_a_step():
    """The same compiled CVXPY step solved by Clarabel and by SCS (another
    algorithm, first-order) reaches the same optimum."""
    sc, path = paper_multi_path_pair(steps_per_segment=1)
    step, model, z, obj = _first_step(sc, path, 0.1)
    s1, x1, _, _ = _solve(step, "CLARABEL", {})
    s2, x2, _, _ = _solve(step, "SCS", {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iters": 200_000})
    assert s1 == "optimal" and s2 in ("optimal", "optimal_inaccurate")
    assert obj(x1) == pytest.approx(obj(x2), rel=1e-3, abs=1e-5)


def test_path_through_an_obstacle_is_refused_with_the_transition_named():
    sc = bn.load_scenario("paper-multi")
    # straight through obstacle 4 (0.27..0.43, 0.23..0.54)
    x = densify(np.array([sc.x0, [0.5, 0.4], [0.65, 0.05]]), 3)
    K = x.shape[0] - 1
    path = bn.BeliefPath.from_sensing(x, sc.P0, np.broadcast_to(1e6 * np.eye(2), (K, 2, 2)), W=sc.W)
    with pytest.raises(InfeasibleStartError) as exc:
        bn.smooth(sc, path)
    assert exc.value.transition is not None and "obstacle" in exc.value.obstacle
    assert f"transition {exc.value.transition}" in str(exc.value)


def test_forced_solver_failure_returns_best_feasible_iterate():
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    res = bn.smooth(sc, path, method="ccp", max_iter=10, _fail_at=3)
    assert not res.success
    assert res.status == "solver_failed"
    assert "iteration 3" in res.message
    assert res.safe and bn.verify(sc, res.path).safe
    accepted = [h.cost for h in res.history if h.accepted]
    assert len(accepted) == 3                      # warm start + iterations 1 and 2
    assert res.cost == pytest.approx(accepted[-1])


def test_resampled_horizon_keeps_vertices_and_smooths():
    sc, path = paper_multi_path_pair(steps_per_segment=1)   # 5 edges
    ws = bn.warm_start(sc, path, K=12)
    assert ws.K == 12
    for v in path.x:                                         # every vertex kept
        assert np.min(np.linalg.norm(ws.path.x - v, axis=1)) < 1e-12
    res = bn.smooth(sc, ws, max_iter=5)
    assert res.safe and res.cost <= res.initial_cost


def test_result_round_trips_through_json(tmp_path, paper_run):
    _, _, res = paper_run
    f = res.save(tmp_path / "res.json")
    back = bn.SmoothResult.load(f)
    assert back.path == res.path
    assert back.cost == res.cost and back.status == res.status
    assert [h.cost for h in back.history] == [h.cost for h in res.history]


@pytest.mark.parametrize("kwargs, field", [
    ({"method": "newton"}, "method"),
    ({"max_iter": 0}, "max_iter"),
    ({"tol": -1.0}, "tol"),
    ({"alpha": -0.5}, "alpha"),
    ({"K": 2}, "K"),
])
def test_bad_options_are_named(kwargs, field):
    sc, path = paper_multi_path_pair(steps_per_segment=1)
    with pytest.raises(ValidationError) as exc:
        bn.smooth(sc, path, **kwargs)
    assert exc.value.field == field


def test_casadi_linearisation_matches_the_analytic_gradients():
    """CCP's tangents come from CasADi: the tangent of log det at Yt is
    log det Yt + tr(Yt^-1 (Y - Yt)); of h = 2 lam^T (A x - b) at (lt, xt) it is
    2 lam^T (A xt - b) + 2 (A^T lt)^T (x - xt)."""
    rng = np.random.default_rng(0)
    d = 2
    Ys = ca.SX.sym("Y", d, d)
    f = tangent(ca.Function("logdet", [Ys], [terms.logdet(Ys)]))
    G = rng.normal(size=(d, d))
    Yt, Y = G @ G.T + np.eye(d), np.eye(d) * 2.0
    ref = np.linalg.slogdet(Yt)[1] + np.trace(np.linalg.solve(Yt, Y - Yt))
    assert float(f(Yt, Y)) == pytest.approx(ref, rel=1e-12)
    F = 3
    ls, xs, As, bs = ca.SX.sym("l", F), ca.SX.sym("x", d), ca.SX.sym("A", F, d), ca.SX.sym("b", F)
    g = tangent(ca.Function("h", [ls, xs, As, bs], [terms.bilinear(ls, xs, As, bs)]), 2)
    A, b = rng.normal(size=(F, d)), rng.normal(size=F)
    lt, xt, lam, x = rng.random(F), rng.normal(size=d), rng.random(F), rng.normal(size=d)
    ref = 2 * lam @ (A @ xt - b) + 2 * (A.T @ lt) @ (x - xt)
    assert float(g(lt, xt, lam, x, A, b)) == pytest.approx(ref, rel=1e-12)


def test_result_files_fail_with_our_errors(tmp_path):
    f = tmp_path / "r.json"
    for content, field in (("{", "filename"), ("[1, 2]", "result"), ("[" * 10000 + "]" * 10000, "filename"),
                           ('{"path": {"x": 1}, "history": []}', None)):
        f.write_text(content)
        with pytest.raises(ValidationError) as exc:
            bn.SmoothResult.load(f)
        assert field is None or exc.value.field == field
    with pytest.raises(ValidationError) as exc:
        bn.SmoothResult.load(tmp_path / "missing.json")
    assert exc.value.field == "filename"
