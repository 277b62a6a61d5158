"""BeliefPath: builders, costs, files, errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from belief_nlp import belief
from belief_nlp.errors import ValidationError
from belief_nlp.path import BeliefPath

W = 2e-4 * np.eye(2)


def _path(K=5, d=2, sensing_every=1, per_metre=False):
    rng = np.random.default_rng(K * 10 + d)
    x = np.cumsum(rng.uniform(0.01, 0.1, size=(K + 1, d)), axis=0)
    S = np.zeros((K, d, d))
    S[sensing_every - 1::sensing_every] = 1e4 * np.eye(d)
    P0 = 1e-6 * np.eye(d)
    if per_metre:
        return BeliefPath.from_sensing(x, P0, S, W_rate=1e-3 * np.eye(d), noise="per_metre")
    return BeliefPath.from_sensing(x, P0, S, W=2e-4 * np.eye(d))


def _raises(fn, field, *words):
    with pytest.raises(ValidationError) as info:
        fn()
    assert info.value.field == field, str(info.value)
    assert field in str(info.value)
    for w in words:
        assert w in str(info.value), str(info.value)


# -------------------------------------------------------------------- builders
def test_from_sensing_rolls_the_kalman_recursion():
    p = _path(K=6, sensing_every=3)
    assert p.K == 6 and p.dim == 2 and p.noise == "per_step"
    assert np.array_equal(p.S[0], np.zeros((2, 2)))
    assert np.array_equal(p.P[0], p.P_prior[0])
    for k in range(1, 7):
        assert np.allclose(p.P_prior[k], p.P[k - 1] + W, rtol=1e-15, atol=0)
        ref = np.linalg.inv(np.linalg.inv(p.P_prior[k]) + p.S[k])
        assert np.allclose(p.P[k], ref, rtol=1e-9, atol=0)
    # Fig. 1 shape: measurements only at k = 3 and 6; elsewhere P = P_hat
    assert p.sensing_steps.tolist() == [3, 6]
    for k in (1, 2, 4, 5):
        assert np.array_equal(p.P[k], p.P_prior[k])


def test_from_sensing_accepts_s_with_or_without_index_0():
    p = _path(K=4)
    q = BeliefPath.from_sensing(p.x, p.P[0], p.S, W=W)           # (K+1, d, d), S[0] ignored
    r = BeliefPath.from_sensing(p.x, p.P[0], p.S[1:], W=W)       # (K, d, d)
    S_junk = p.S.copy()
    S_junk[0] = 5.0
    s = BeliefPath.from_sensing(p.x, p.P[0], S_junk, W=W)
    assert p == q == r == s


def test_from_covariances_recovers_sensing():
    p = _path(K=5)
    q = BeliefPath.from_covariances(p.x, p.P, W=W)
    assert np.array_equal(q.P, p.P)
    assert np.allclose(q.P_prior, p.P_prior, rtol=1e-15, atol=0)
    assert np.allclose(q.S, p.S, rtol=1e-6, atol=1e-6 * 1e4)
    # a path that is not lossless gets an indefinite S
    P = p.P.copy()
    P[3] = P[2] + 2 * W + np.diag([1e-4, 0.0])
    bad = BeliefPath.from_covariances(p.x, P, W=W)
    assert np.linalg.eigvalsh(bad.S[3])[0] < 0


def test_per_metre_noise():
    p = _path(K=4, per_metre=True)
    lengths = np.linalg.norm(np.diff(p.x, axis=0), axis=1)
    assert np.allclose(p.transition_noise, lengths[:, None, None] * 1e-3 * np.eye(2), rtol=1e-12, atol=1e-20)
    q = BeliefPath.from_covariances(p.x, p.P, W_rate=1e-3 * np.eye(2), noise="per_metre")
    assert q.noise == "per_metre" and np.allclose(q.P_prior, p.P_prior, rtol=1e-14, atol=0)


def test_per_step_noise_may_vary_by_transition():
    x = np.array([[0, 0], [0.1, 0], [0.2, 0]], float)
    Wk = np.stack([W, 2 * W])
    p = BeliefPath.from_sensing(x, np.zeros((2, 2)), np.zeros((2, 2, 2)), W=Wk)
    assert np.allclose(p.transition_noise, Wk)


def test_three_d_path():
    p = _path(K=3, d=3)
    assert p.dim == 3 and p.P.shape == (4, 3, 3)


# ----------------------------------------------------------------------- costs
def test_cost_breakdown():
    p = _path(K=5, sensing_every=2)
    alpha = 0.7
    c = p.cost_breakdown(alpha)
    dx = np.diff(p.x, axis=0)
    info_ref = sum(0.5 * (np.linalg.slogdet(p.P_prior[k])[1] - np.linalg.slogdet(p.P[k])[1]) for k in range(1, 6))
    assert c["alpha"] == alpha
    assert c["control"] == pytest.approx(np.sum(dx**2), rel=1e-14)
    assert c["length"] == pytest.approx(np.sum(np.linalg.norm(dx, axis=1)), rel=1e-14)
    assert c["information_nats"] == pytest.approx(info_ref, rel=1e-10)
    assert c["information_bits"] == pytest.approx(info_ref / math.log(2), rel=1e-10)
    assert c["steering"] == pytest.approx(c["control"] + alpha * info_ref, rel=1e-10)
    assert c["planner"] == pytest.approx(c["length"] + alpha * info_ref, rel=1e-10)
    assert c["steering"] == pytest.approx(p.steering_cost(alpha)) and c["planner"] == pytest.approx(p.planner_cost(alpha))
    total, control, info = belief.path_steering_cost(p.x, p.P_prior, p.P, alpha)
    assert total == pytest.approx(c["steering"], rel=1e-12)
    assert np.sum(p.step_control) == pytest.approx(c["control"])
    assert np.sum(p.step_information) == pytest.approx(c["information_nats"])
    assert p.sensing_steps.tolist() == [2, 4]
    assert p.step_information.shape == (5,) and np.all(p.step_information[1::2] > 0)
    assert np.all(p.step_information[::2] == 0)  # no sensing, no information (exactly)
    json.dumps(c)


# ----------------------------------------------------------------------- files
@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_save_load_round_trip(tmp_path, suffix):
    for p in (_path(K=5), _path(K=3, d=3), _path(K=4, per_metre=True)):
        p.meta = {"planner": "ig-rrt*", "seed": 3, "nested": {"a": [1, 2.5]}}
        back = BeliefPath.load(p.save(tmp_path / f"p{suffix}"))
        assert back == p
        for f in ("x", "P", "P_prior", "S"):
            assert np.array_equal(getattr(back, f), getattr(p, f))
        assert back.noise == p.noise and back.meta == p.meta


def test_load_path_inside_a_result_file(tmp_path):
    p = _path(K=3)
    f = tmp_path / "result.json"
    f.write_text(json.dumps({"method": "ccp", "path": p.to_dict()}))
    assert BeliefPath.load(f) == p


def test_equality():
    p = _path(K=3)
    q = BeliefPath.from_dict(p.to_dict())
    assert p == q
    with pytest.raises(ValueError):          # validated arrays are read-only
        q.x[1, 0] += 1e-12
    x = q.x.copy()
    x[1, 0] += 1e-12
    assert p != BeliefPath(x, q.P, q.P_prior, q.S)
    assert p != "path"


# ---------------------------------------------------------------------- errors
def test_constructor_shape_errors():
    p = _path(K=3)
    _raises(lambda: BeliefPath(p.x[:, 0], p.P, p.P_prior, p.S), "path.x", "(K+1, d)")
    _raises(lambda: BeliefPath(p.x[:1], p.P[:1], p.P_prior[:1], p.S[:1]), "path.x", "two points")
    _raises(lambda: BeliefPath(p.x, p.P[:-1], p.P_prior, p.S), "path.P", "(4, 2, 2)")
    _raises(lambda: BeliefPath(p.x, p.P, p.P_prior[:, :1], p.S), "path.P_prior", "shape")
    _raises(lambda: BeliefPath(p.x, p.P, p.P_prior, p.S[..., None]), "path.S", "shape")
    x = p.x.copy()
    x[2, 1] = np.nan
    _raises(lambda: BeliefPath(x, p.P, p.P_prior, p.S), "path.x", "NaN")
    _raises(lambda: BeliefPath(p.x, p.P, p.P_prior, p.S, noise="per_second"), "path.noise", "per_step")
    _raises(lambda: BeliefPath(p.x, p.P, p.P_prior, p.S, meta=[1]), "path.meta", "dict")
    _raises(lambda: BeliefPath([[0, 0], [1]], p.P[:2], p.P_prior[:2], p.S[:2]), "path.x", "rectangular")
    _raises(lambda: BeliefPath("xy", p.P, p.P_prior, p.S), "path.x", "numbers")


def test_builder_shape_errors():
    x = np.zeros((4, 2))
    S = np.zeros((3, 2, 2))
    P0 = np.eye(2) * 1e-6
    _raises(lambda: BeliefPath.from_sensing(np.zeros(4), P0, S, W=W), "x", "(K+1, d)")
    _raises(lambda: BeliefPath.from_sensing(np.zeros((1, 2)), P0, S[:0], W=W), "x", "K >= 1")
    _raises(lambda: BeliefPath.from_sensing(x, P0, np.zeros((2, 2, 2)), W=W), "S", "(3, 2, 2)", "(4, 2, 2)")
    _raises(lambda: BeliefPath.from_sensing(x, P0, np.zeros((2, 2)), W=W), "S", "shape")
    _raises(lambda: BeliefPath.from_sensing(x, np.eye(3), S, W=W), "P0", "(2, 2)")
    _raises(lambda: BeliefPath.from_sensing(x, P0, S), "W", "needs W")
    _raises(lambda: BeliefPath.from_sensing(x, P0, S, W=np.eye(3)), "W", "(2, 2)")
    _raises(lambda: BeliefPath.from_sensing(x, P0, S, noise="per_metre"), "W_rate", "needs W_rate")
    _raises(lambda: BeliefPath.from_sensing(x, P0, S, W_rate=np.eye(3), noise="per_metre"), "W_rate", "(2, 2)")
    _raises(lambda: BeliefPath.from_sensing(x, P0, S, W=W, noise="per_hour"), "noise", "per_step")
    _raises(lambda: BeliefPath.from_covariances(x, np.zeros((3, 2, 2)), W=W), "P", "(4, 2, 2)")


def test_file_errors(tmp_path):
    p = _path(K=2)
    _raises(lambda: p.save(tmp_path / "p.csv"), "path", ".csv")
    _raises(lambda: BeliefPath.load(tmp_path / "missing.json"), "path", "no such file")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    _raises(lambda: BeliefPath.load(bad), "path", "malformed JSON")
    d = p.to_dict()
    del d["S"]
    _raises(lambda: BeliefPath.from_dict(d), "path.S", "missing")
    d = p.to_dict()
    d["colour"] = 1
    _raises(lambda: BeliefPath.from_dict(d), "path.colour", "unknown")
    d = p.to_dict()
    d["meta"] = "x"
    _raises(lambda: BeliefPath.from_dict(d), "path.meta", "object")
    _raises(lambda: BeliefPath.from_dict([1, 2]), "path", "object")
    npz = tmp_path / "short.npz"
    np.savez(npz, x=p.x, P=p.P)
    _raises(lambda: BeliefPath.load(npz), "path.P_prior", "missing")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    _raises(lambda: BeliefPath.load(junk), "path", "NPZ")
