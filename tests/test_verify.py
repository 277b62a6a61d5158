"""The independent verifier: safe paths pass, each kind of fault is caught and named."""

from __future__ import annotations

import json

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import geometry
from belief_nlp.errors import ValidationError
from belief_nlp.path import BeliefPath


def densify(waypoints, per: int) -> np.ndarray:
    wp = np.asarray(waypoints, dtype=float)
    t = np.arange(1, per + 1)[:, None] / per
    return np.vstack([wp[:1]] + [wp[i] + t * (wp[i + 1] - wp[i]) for i in range(len(wp) - 1)])


def sensed_path(sc, x, s=1e4, **kw) -> BeliefPath:
    K, d = x.shape[0] - 1, x.shape[1]
    S = np.broadcast_to(s * np.eye(d), (K, d, d))
    if kw.get("noise") == "per_metre":
        return BeliefPath.from_sensing(x, sc.P0, S, W_rate=kw.pop("W_rate", sc.W_rate), **kw)
    return BeliefPath.from_sensing(x, sc.P0, S, W=kw.pop("W", sc.W), **kw)


def random_path(sc, rng, K, smax=5.0) -> BeliefPath:
    """Means anywhere in the domain's box, sensing with random orientation and scale."""
    d = sc.dim
    lo, hi = sc.domain.bounding_box()
    x = np.vstack([sc.x0, rng.uniform(lo, hi, size=(K, d))])
    S = []
    for _ in range(K):
        Q = np.linalg.qr(rng.normal(size=(d, d)))[0]
        S.append((Q * 10.0 ** rng.uniform(0, smax, d)) @ Q.T)
    return BeliefPath.from_sensing(x, sc.P0, np.array(S), W=sc.W)


CUBE_ROUTE = [(0.15, 0.15, 0.15), (0.15, 0.8, 0.3), (0.6, 0.88, 0.6), (0.825, 0.825, 0.825)]


# ------------------------------------------------------------------- safe paths
def test_hand_made_paper_multi_path_is_safe(paper_multi_path):
    sc, path = paper_multi_path
    rep = bn.verify(sc, path)
    assert rep.safe and bool(rep) and rep.problems == []
    assert rep.min_margin > 0
    assert rep.transition_margins.shape == (path.K, len(sc.hazards))
    assert rep.hazard_names == [h.name for h in sc.hazards]
    assert np.all(rep.target_margins_m > 0)
    assert np.max(rep.kalman_residual) < 1e-9 and np.max(rep.noise_residual) < 1e-9
    assert np.all(rep.sensing_min_eig >= 0) and rep.start_residual == 0.0
    assert rep.summary().startswith("SAFE")
    assert rep.worst.startswith("transition") or rep.worst.startswith("target")
    json.dumps(rep.to_dict())


def test_cube3d_path_is_safe_and_a_3d_collision_is_named():
    sc = bn.load_scenario("cube3d")
    good = sensed_path(sc, densify(CUBE_ROUTE, 3))
    rep = bn.verify(sc, good)
    assert rep.safe, rep.summary()
    # straight through the slab (obstacle 1) to the target
    bad = sensed_path(sc, densify([CUBE_ROUTE[0], (0.825, 0.4, 0.5), CUBE_ROUTE[-1]], 3))
    rep = bn.verify(sc, bad)
    assert not rep.safe and "obstacle 1" in rep.worst
    assert any("collides with obstacle 1" in p for p in rep.problems)


def test_exact_start_p0_zero():
    sc = bn.load_scenario("quad").with_options(P0=np.zeros((2, 2)))
    x = densify([(0.1, 0.9), (0.1, 0.5), (0.45, 0.45), (0.85, 0.05)], 5)
    rep = bn.verify(sc, sensed_path(sc, x))
    assert rep.safe, rep.summary()


# -------------------------------------------------------------------- failures
def test_path_through_an_obstacle_fails_and_names_it(paper_multi_path):
    sc, path = paper_multi_path
    x = path.x.copy()
    x[10] = np.mean(sc.obstacles[5].vertices, axis=0)   # into obstacle 6
    rep = bn.verify(sc, sensed_path(sc, x))
    assert not rep.safe and rep.min_margin < 0
    assert "obstacle 6" in rep.worst
    assert any("transition 10 collides with obstacle 6" in p for p in rep.problems)
    assert any("transition 11 collides with obstacle 6" in p for p in rep.problems)
    assert "UNSAFE" in rep.summary() and "obstacle 6" in rep.summary()
    j = rep.hazard_names.index("obstacle 6")
    assert rep.transition_margins[9, j] == pytest.approx(-sc.chi2)  # the mean is inside


def test_clear_end_ellipses_but_colliding_middle_fails():
    """One step jumps across obstacle 2: both end ellipses are clear, the
    transition is not (paper Definition 3)."""
    sc = bn.load_scenario("paper-multi")
    x = np.vstack([densify([(0.15, 0.5), (0.15, 0.66)], 3),
                   densify([(0.40, 0.66), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)], 4)])
    path = sensed_path(sc, x)
    ob = sc.obstacles[1]
    k = 3  # transition 4: x[3] = (0.15, 0.66) -> x[4] = (0.40, 0.66)
    assert geometry.ellipse_clearance(x[k], path.P[k], ob.A, ob.b, sc.chi2) > 0
    assert geometry.ellipse_clearance(x[k + 1], path.P_prior[k + 1], ob.A, ob.b, sc.chi2) > 0
    assert geometry.ellipse_clearance(x[k + 1], path.P[k + 1], ob.A, ob.b, sc.chi2) > 0
    rep = bn.verify(sc, path)
    assert not rep.safe
    assert rep.worst == "transition 4 vs obstacle 2"
    assert [p for p in rep.problems if "collides" in p] == [
        f"transition 4 collides with obstacle 2 (margin {rep.min_margin:.4g})"]


def test_grazing_ellipse_without_the_mean_inside_fails():
    """A big covariance near a wall: the mean stays inside the domain, the
    ellipse crosses the wall in the middle of a transition."""
    sc = bn.load_scenario("paper-multi")
    x = densify([(0.15, 0.5), (0.15, 0.8), (0.45, 0.8), (0.75, 0.7), (0.82, 0.33), (0.65, 0.05)], 4)
    x[8] = (0.45, 0.93)          # 7 cm below the top wall
    S = np.broadcast_to(1e4 * np.eye(2), (20, 2, 2)).copy()
    S[7] = 0.0                    # no measurement before it: a bigger ellipse
    S[6] = 0.0
    path = BeliefPath.from_sensing(x, sc.P0, S, W=sc.W * 6)
    rep = bn.verify(sc.with_options(W=sc.W * 6), path)
    assert any("wall" in p for p in rep.problems), rep.summary()
    assert np.all(x[1:] < 1.0)


def test_final_ellipse_outside_the_target_fails(paper_multi_path):
    sc, path = paper_multi_path
    # stop two steps early: the mean is far from the target
    short = sensed_path(sc, path.x[:-2])
    rep = bn.verify(sc, short)
    assert not rep.safe and any("leaves the target" in p for p in rep.problems)
    # end with the mean inside the target but the ellipse across its right face
    x = path.x.copy()
    x[-1] = (0.695, 0.05)
    edge = sensed_path(sc, x)
    rep = bn.verify(sc, edge)
    assert sc.target.contains(x[-1])
    assert not rep.safe and any("leaves the target across face" in p for p in rep.problems)
    assert "target face" in rep.worst
    assert np.min(rep.target_margins_m) < 0


def test_kalman_inconsistent_path_fails(paper_multi_path):
    sc, path = paper_multi_path
    S = path.S.copy()
    S[5] *= 2.0                   # claims twice the sensing that produced P_5
    bad = BeliefPath(path.x, path.P, path.P_prior, S)
    rep = bn.verify(sc, bad)
    assert not rep.safe
    assert any("P_5 is not the Kalman update" in p for p in rep.problems)
    assert rep.kalman_residual[4] > 1e-6 and np.all(np.delete(rep.kalman_residual, 4) < 1e-9)


def test_indefinite_sensing_fails(paper_multi_path):
    sc, path = paper_multi_path
    P = path.P.copy()
    P[7] = path.P_prior[7] + np.diag([2e-5, 0.0])    # bigger than the prior in x: not lossless
    P[7][1, 1] *= 0.5
    bad = BeliefPath.from_covariances(path.x, P, W=sc.W)
    rep = bn.verify(sc, bad)
    assert not rep.safe
    assert any(p.startswith("S_7 is not positive semidefinite") for p in rep.problems), rep.summary()
    assert rep.sensing_min_eig[6] < 0
    assert not any("Kalman" in p for p in rep.problems)  # consistent, just not lossless


def test_per_metre_path_is_checked_against_w_rate(paper_multi_path):
    sc, ref = paper_multi_path
    good = sensed_path(sc, ref.x, noise="per_metre")
    rep = bn.verify(sc, good)
    assert rep.safe, rep.summary()
    assert np.max(rep.noise_residual) < 1e-9
    # the same means with twice the noise rate
    bad = sensed_path(sc, ref.x, noise="per_metre", W_rate=2 * sc.W_rate)
    rep = bn.verify(sc, bad)
    assert not rep.safe and any("per_metre model" in p for p in rep.problems)
    # a per-step path checked as per-step against W passes; relabelled per-metre it fails
    relabelled = BeliefPath(ref.x, ref.P, ref.P_prior, ref.S, noise="per_metre")
    rep = bn.verify(sc, relabelled)
    assert any("noise does not match the scenario's per_metre model" in p for p in rep.problems)


def test_per_step_noise_mismatch_fails(paper_multi_path):
    sc, ref = paper_multi_path
    bad = sensed_path(sc, ref.x, W=1.5 * sc.W)
    rep = bn.verify(sc, bad)
    assert not rep.safe and any("per_step model" in p for p in rep.problems)


def test_start_mismatch_fails(paper_multi_path):
    sc, ref = paper_multi_path
    moved = sensed_path(sc.with_options(x0=np.array([0.16, 0.5])), np.vstack([[0.16, 0.5], ref.x[1:]]))
    rep = bn.verify(sc, moved)
    assert any("does not start at the scenario's start" in p for p in rep.problems)
    other_P0 = BeliefPath.from_sensing(ref.x, 2e-9 * np.eye(2), ref.S, W=sc.W)
    rep = bn.verify(sc, other_P0)
    assert any("does not start" in p for p in rep.problems)


def test_non_psd_covariance_is_reported_not_crashed(paper_multi_path):
    sc, ref = paper_multi_path
    P = ref.P.copy()
    P[4] = np.diag([1e-4, -1e-5])
    Pp = ref.P_prior.copy()
    Pp[5] = P[4] + sc.W
    rep = bn.verify(sc, BeliefPath(ref.x, P, Pp, ref.S))
    assert not rep.safe
    assert any("P_4 is not a covariance" in p for p in rep.problems)


def test_bad_arguments():
    sc2 = bn.load_scenario("paper-multi")
    sc3 = bn.load_scenario("cube3d")
    path3 = sensed_path(sc3, densify(CUBE_ROUTE, 1))
    with pytest.raises(ValidationError) as info:
        bn.verify(sc2, path3)
    assert info.value.field == "path.x" and "3-D" in str(info.value) and "2-D" in str(info.value)
    with pytest.raises(ValidationError) as info:         # a name is loaded, then checked like a Scenario
        bn.verify("paper-multi", path3)
    assert info.value.field in ("path.x", "scenario") and "3-D" in str(info.value)
    assert bn.verify("cube3d", path3).safe == bn.verify(sc3, path3).safe
    with pytest.raises(ValidationError) as info:
        bn.verify(sc3, path3, n_samples=1)
    assert info.value.field == "n_samples"


# ------------------------------------------- sampled margins vs exact geometry
@pytest.mark.parametrize("name, n_paths", [("paper-multi", 6), ("tutorial", 4), ("quad", 4)])
def test_sampled_margins_agree_with_exact_geometry_2d(name, n_paths):
    sc = bn.load_scenario(name)
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    for _ in range(n_paths):
        path = random_path(sc, rng, K=8)
        rep = bn.verify(sc, path)
        exact = geometry.transition_clearances(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise,
                                               list(sc.hazards), sc.chi2)
        scale = np.abs(exact) + sc.chi2
        diff = rep.transition_margins - exact
        # sampling can only overestimate a minimum over s ...
        assert np.all(diff >= -1e-9 * scale)
        # ... and the refined grid gets close to it
        assert np.all(diff <= 1e-3 * scale), np.max(diff / scale)


def test_sampled_margins_agree_with_exact_geometry_3d_obstacles():
    sc = bn.load_scenario("cube3d")
    rng = np.random.default_rng(5)
    for _ in range(3):
        path = random_path(sc, rng, K=5)
        rep = bn.verify(sc, path)
        m = len(sc.obstacles)
        exact = geometry.transition_clearances(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise,
                                               list(sc.obstacles), sc.chi2)
        scale = np.abs(exact) + sc.chi2
        diff = rep.transition_margins[:, :m] - exact
        assert np.all(diff >= -1e-9 * scale)
        assert np.all(diff <= 1e-3 * scale), np.max(diff / scale)


def test_3d_wall_margins_match_closed_form():
    """A wall {a^T y >= beta} against a transition: the squared distance
    (a^T x(s) - beta)^2 / a^T P(s) a, minimised over a fine grid of s."""
    sc = bn.load_scenario("cube3d")
    path = random_path(sc, np.random.default_rng(11), K=4)
    rep = bn.verify(sc, path)
    s = np.linspace(0, 1, 20001)
    m = len(sc.obstacles)
    for j, wall in enumerate(sc.walls):
        a, beta = wall.A[0], wall.b[0]
        for k in range(path.K):
            xs = path.x[k] + s[:, None] * (path.x[k + 1] - path.x[k])
            t = xs @ a - beta
            var = a @ path.P[k] @ a + s * (a @ path.transition_noise[k] @ a)
            ref = np.min(np.where(t <= 0, 0.0, t * t / var)) - sc.chi2
            assert rep.transition_margins[k, m + j] == pytest.approx(ref, rel=1e-6, abs=1e-9)


def test_sampled_margins_agree_with_exact_geometry_3d_walls():
    sc = bn.load_scenario("cube3d")
    path = random_path(sc, np.random.default_rng(3), K=4)
    rep = bn.verify(sc, path)
    exact = geometry.transition_clearances(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise,
                                           list(sc.walls), sc.chi2)
    diff = rep.transition_margins[:, len(sc.obstacles):] - exact
    scale = np.abs(exact) + sc.chi2
    assert np.all(diff >= -1e-9 * scale) and np.all(diff <= 1e-3 * scale)


def test_the_closed_form_2x2_factor_is_the_stacked_cholesky_and_falls_back_like_it():
    """The verifier factors every sampled 2x2 covariance in closed form
    (``_chol2``, LAPACK's operations) and shares that factor across the
    polygons: it equals ``np.linalg.cholesky`` of the same symmetrised,
    jittered stack (to rounding: bit for bit with this machine's OpenBLAS),
    and where one matrix is not positive definite the whole stack takes
    ``_chol``'s PSD-part factors, as before; the polygon distances with a
    shared factor equal those that factor per call."""
    from belief_nlp._verify_distances import _chol, _chol2, _sqdist_polygon

    rng = np.random.default_rng(3)
    B = rng.normal(size=(5000, 2, 2)) * 10.0 ** rng.uniform(-6, 1, size=(5000, 1, 1))
    P = B @ B.transpose(0, 2, 1) + 1e-12 * np.eye(2)
    L = np.linalg.cholesky(0.5 * (P + P.transpose(0, 2, 1)) + 1e-30 * np.eye(2))
    for got, want in zip(_chol2(P), (L[:, 0, 0], L[:, 1, 0], L[:, 1, 1])):
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)
    V = np.array([[0.0, 0.0], [1.0, 0.0], [1.2, 0.8], [0.3, 1.1]])
    x = rng.normal(size=(5000, 2))
    assert np.array_equal(_sqdist_polygon(x, P, V, _chol2(P)), _sqdist_polygon(x, P, V))
    P[7] = [[1.0, 0.0], [0.0, -1e-20]]            # not positive definite (its PSD part is)
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(P[7])
    L = _chol(P)
    for got, want in zip(_chol2(P), (L[:, 0, 0], L[:, 1, 0], L[:, 1, 1])):
        assert np.array_equal(got, want)
