"""belief_nlp.export: CasADi functions checked against the numpy geometry and
belief maths, serialisation, MPC-tool conventions and the MPC demo."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import belief, export, geometry
from belief_nlp.errors import ValidationError

RNG = np.random.default_rng(7)


def spd(d: int, scale: float, rng=RNG) -> np.ndarray:
    M = rng.normal(size=(d, d))
    return scale * (M @ M.T / d + 0.1 * np.eye(d))


def psd_rank(d: int, r: int, scale: float, rng=RNG) -> np.ndarray:
    V = rng.normal(size=(d, r))
    return scale * V @ V.T


@pytest.fixture(scope="module")
def multi():
    return bn.load_scenario("paper-multi")


@pytest.mark.parametrize("d", [2, 3])
def test_belief_functions_match_numpy(d):
    pred, upd, info = export.belief_predict(d), export.belief_update(d), export.information_cost(d)
    for trial in range(20):
        P = spd(d, 10 ** RNG.uniform(-9, -3))           # down to the start covariance 1e-9 I
        W = spd(d, 2e-4)
        S = [np.zeros((d, d)), psd_rank(d, 1, 10 ** RNG.uniform(1, 5)), spd(d, 10 ** RNG.uniform(1, 5))][trial % 3]
        Ph = np.asarray(pred(P, W))
        np.testing.assert_allclose(Ph, belief.predict(P, W))
        Pp = np.asarray(upd(Ph, S))
        np.testing.assert_allclose(Pp, belief.update(Ph, S), rtol=1e-8, atol=1e-14)
        nats = float(info(Ph, S))
        assert nats == pytest.approx(float(belief.information_cost(Ph, belief.update(Ph, S))), rel=1e-7, abs=1e-10)
    assert upd.name() == "belief_update" and upd.name_in() == ["P_hat", "S"] and upd.name_out() == ["P"]
    assert info.name_out() == ["nats"] and pred.name_in() == ["P", "W"]


def _random_belief(sc, rng=RNG):
    lo, hi = sc.domain.bounding_box()
    x = rng.uniform(lo, hi)
    P = spd(sc.dim, 10 ** rng.uniform(-4.5, -3))
    return x, P


@pytest.mark.parametrize("name", ["paper-multi", "cube3d"])
def test_ellipse_clearance_matches_geometry(name):
    sc = bn.load_scenario(name)
    fns = export.export_functions(sc)
    checked = 0
    for _ in range(40):
        x, P = _random_belief(sc)
        for h in sc.hazards:
            f = fns[f"clearance_{export._slug(h.name)}"]
            exact = geometry.ellipse_clearance(x, P, h.A, h.b, sc.chi2)
            lam = geometry.ellipse_certificate(x, P, h.A, h.b)
            if exact > -sc.chi2:                     # mean outside: the maximiser attains the distance
                assert float(f(x, P, lam)) == pytest.approx(exact, rel=1e-6, abs=1e-6 * (1 + abs(exact)))
                checked += 1
            # weak duality: any lam >= 0 gives a lower bound
            other = RNG.uniform(0, 2, size=h.n_faces) * (np.abs(lam).max() + 1.0)
            assert float(f(x, P, other)) <= exact + 1e-6 * (1 + abs(exact))
    assert checked > 50


def test_clearance_with_polytope_inputs(multi):
    h = multi.obstacles[0]
    f_in = export.ellipse_clearance(2, multi.chi2, n_faces=h.n_faces)
    f_fix = export.ellipse_clearance(2, multi.chi2, h.A, h.b)
    assert f_in.name_in() == ["x", "P", "lam", "A", "b"] and f_fix.name_in() == ["x", "P", "lam"]
    x, P = np.array([0.3, 0.45]), spd(2, 1e-3)
    lam = RNG.uniform(0, 50, size=h.n_faces)
    assert float(f_in(x, P, lam, h.A, h.b)) == pytest.approx(float(f_fix(x, P, lam)))
    t_in = export.transition_clearance(2, multi.chi2, n_faces=h.n_faces)
    t_fix = export.transition_clearance(2, multi.chi2, h.A, h.b)
    a = t_in(x, P, x + 0.01, multi.W, lam, h.A, h.b)
    b = t_fix(x, P, x + 0.01, multi.W, lam)
    assert float(a[0]) == pytest.approx(float(b[0])) and float(a[1]) == pytest.approx(float(b[1]))


@pytest.mark.parametrize("name", ["paper-multi", "cube3d"])
def test_transition_clearance_matches_geometry(name):
    sc = bn.load_scenario(name)
    fns = export.export_functions(sc)
    n_tight = 0
    for _ in range(25):
        x0, P0 = _random_belief(sc)
        x1 = x0 + RNG.normal(scale=0.05, size=sc.dim)
        for h in sc.hazards:
            f = fns[f"transition_{export._slug(h.name)}"]
            assert f.name_out() == ["margin_start", "margin_end"]
            exact = geometry.transition_clearance(x0, P0, x1, sc.W, h.A, h.b, sc.chi2)
            lam, value = geometry.transition_certificate(x0, P0, x1, sc.W, h.A, h.b)
            m0, m1 = (float(v) for v in f(x0, P0, x1, sc.W, lam))
            # the margins are those of the certificate's value, and never exceed the exact clearance
            assert min(m0, m1) == pytest.approx(value - sc.chi2, rel=1e-6, abs=1e-6 * (1 + abs(value)))
            assert min(m0, m1) <= exact + 1e-6 * (1 + abs(exact))
            if exact > 0:                            # a clear transition is certified (Theorem 1)
                assert min(m0, m1) >= -1e-6 * (1 + abs(exact))
                n_tight += abs(min(m0, m1) - exact) <= 1e-4 * (1 + abs(exact))
    assert n_tight > 20


@pytest.mark.parametrize("name", ["paper-multi", "cube3d"])
def test_target_containment_matches_geometry(name):
    sc = bn.load_scenario(name)
    f = export.export_functions(sc)["target_containment"]
    lo, hi = sc.target.bounding_box()
    for _ in range(30):
        x = RNG.uniform(lo - 0.05, hi + 0.05)
        P = spd(sc.dim, 10 ** RNG.uniform(-6, -3))
        np.testing.assert_allclose(np.asarray(f(x, P)).ravel(),
                                   geometry.containment_margins(x, P, sc.target.A, sc.target.b, sc.chi2),
                                   rtol=1e-10, atol=1e-12)


def test_functions_are_sx_and_inline(multi):
    fns = export.export_functions(multi)
    assert {"belief_predict", "belief_update", "information_cost", "target_containment",
            "clearance_obstacle_1", "transition_obstacle_1", "transition_wall_3"} <= set(fns)
    assert len([k for k in fns if k.startswith("transition_")]) == len(multi.hazards)
    for key, fn in fns.items():
        assert fn.is_a("SXFunction") and fn.name() == key
    # SX call -> plain expressions (an SX model can expand and differentiate them)
    x = ca.SX.sym("x", 2)
    P = ca.SX.sym("P", 2, 2)
    lam = ca.SX.sym("lam", 4)
    m0, m1 = fns["transition_obstacle_1"](x, P, x + 0.01, multi.W, lam)
    assert isinstance(m0, ca.SX) and ca.jacobian(m1, lam).shape == (1, 4)
    # MX call (casadi.Opti)
    opti = ca.Opti()
    xm = opti.variable(2)
    assert isinstance(fns["target_containment"](xm, np.eye(2) * 1e-4), ca.MX)


def test_save_and_load_round_trip(multi, tmp_path):
    fns = export.export_functions(multi)
    written = export.save_functions(fns, tmp_path / "fns")
    assert len(written) == len(fns) and all(p.suffix == ".casadi" for p in written)
    back = export.load_functions(tmp_path / "fns")
    assert set(back) == set(fns)
    P = spd(2, 1e-3)
    for key, fn in fns.items():
        args = [RNG.uniform(0.1, 1.0, size=fn.size_in(i)) if fn.name_in(i) in ("x", "x_prev", "x_next", "lam")
                else (P if fn.name_in(i) in ("P", "P_prev", "P_hat") else multi.W if fn.name_in(i) == "W"
                      else spd(2, 1e3)) for i in range(fn.n_in())]
        for a, b in zip(fn(*args) if fn.n_out() > 1 else [fn(*args)],
                        back[key](*args) if fn.n_out() > 1 else [back[key](*args)]):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert back[key].name_in() == fn.name_in() and back[key].name_out() == fn.name_out()
    # a single Function with the plain CasADi calls
    fns["belief_update"].save(str(tmp_path / "upd.casadi"))
    upd = ca.Function.load(str(tmp_path / "upd.casadi"))
    S = spd(2, 1e3)
    np.testing.assert_allclose(np.asarray(upd(P, S)), belief.update(P, S), rtol=1e-9)


def test_dompc_and_acados_conventions(multi):
    J = len(multi.hazards)
    F = sum(h_.n_faces for h_ in multi.hazards)
    x0, P0 = np.array([0.15, 0.5]), 1e-4 * np.eye(2)
    x1 = np.array([0.15, 0.55])
    lams = [geometry.transition_certificate(x0, P0, x1, multi.W, h.A, h.b)[0] for h in multi.hazards]
    names, h = export.clearance_margins(multi, x0, P0, x1, lams, x_final=x1, P_final=P0)
    h = np.asarray(h).ravel()
    assert len(names) == 2 * J + F + multi.target.n_faces == h.size
    assert names[:3] == ["obstacle_1_start", "obstacle_1_end", "obstacle_1_lam_0"]
    assert names[-1] == f"target_face_{multi.target.n_faces - 1}"
    # do-mpc: expr <= ub with expr = -margin, ub = -required margin (0 for the lam >= 0 rows)
    cons = export.dompc_constraints(multi, x0, P0, x1, lams, margin=0.5)
    assert [c[0] for c in cons] == names[:2 * J + F]
    for (name, expr, ub), m in zip(cons, h):
        assert float(expr) == pytest.approx(-m) and ub == (0.0 if "_lam_" in name else -0.5)
    # acados: lh <= h <= uh, one-sided
    hh, lh, uh = export.acados_constraints(multi, x0, P0, x1, lams, x_final=x1, P_final=P0)
    np.testing.assert_allclose(np.asarray(hh).ravel(), h)
    assert lh.shape == uh.shape == (h.size,) and np.all(lh == 0) and np.all(uh == export.ACADOS_INFTY)
    # symbolic use: expressions of the caller's symbols
    xs = ca.SX.sym("x", 2)
    lam_s = [ca.SX.sym(f"l{j}", h_.n_faces) for j, h_ in enumerate(multi.hazards)]
    hs, _, _ = export.acados_constraints(multi, x0, P0, xs, lam_s)
    assert isinstance(hs, ca.SX) and hs.shape == (2 * J + F, 1)


def test_a_belief_inside_an_obstacle_is_never_clear_whatever_the_certificates(multi):
    """The drift the symbolic-model issue found: a belief at the centroid of
    obstacle 1 (P = 1e-6 I) with lam = -1e3 scored 'clear'. With the lam >= 0
    rows shipped in every helper, no certificate satisfies all rows."""
    ob = multi.obstacles[0]
    c = ob.vertices.mean(axis=0)
    P = 1e-6 * np.eye(2)
    rng = np.random.default_rng(0)
    for scale in (-1e3, -1.0, 1.0, 1e3):
        lams = [scale * np.abs(rng.normal(size=h.n_faces)) * (1 if j else np.sign(scale))
                for j, h in enumerate(multi.hazards)]
        lams[0] = scale * np.ones(ob.n_faces)
        names, h = export.clearance_margins(multi, c, P, c, lams)
        h = np.asarray(h).ravel()
        rows = [i for i, n in enumerate(names) if n.startswith("obstacle_1_")]
        assert np.min(h[rows]) < 0, scale
        hh, lh, _ = export.acados_constraints(multi, c, P, c, lams)
        assert np.any(np.asarray(hh).ravel()[rows] < lh[rows])


def test_bad_arguments(multi):
    with pytest.raises(ValidationError):
        export.ellipse_clearance(2)                                  # chi2 missing
    with pytest.raises(ValidationError):
        export.ellipse_clearance(2, 4.6, A=np.eye(2))                # b missing
    with pytest.raises(ValidationError):
        export.transition_clearance(2, 4.6)                          # n_faces missing with A, b inputs
    with pytest.raises(ValidationError):
        export.belief_update(0)
    with pytest.raises(ValidationError):
        export.clearance_margins(multi, np.zeros(2), np.eye(2), np.zeros(2), [np.zeros(4)])
    with pytest.raises(ValidationError):
        export.mpc_demo(steps=0)


def test_mpc_demo_closed_loop_is_verified():
    """A receding-horizon MPC in casadi.Opti made of the exported functions
    takes the robot past the obstacle; its closed-loop beliefs pass verify."""
    sc = export.demo_scenario()
    path = export.mpc_demo(steps=12, horizon=6)
    assert path.K == 12 and path.meta["method"] == "mpc_demo"
    report = bn.verify(sc, path)
    assert report.safe, report.summary()
    assert sc.target.contains(path.x[-1])
    assert path.sensing_steps.size > 0                   # it had to measure to fit into the target
    # it went around the obstacle (above or below), never through its x-range at mid height
    mid = (path.x[:, 0] > 0.4) & (path.x[:, 0] < 0.6)
    assert np.all((path.x[mid, 1] > 0.3) | (path.x[mid, 1] < 0.1))
