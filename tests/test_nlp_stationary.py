"""Stationarity of a polished answer for its switched-off sensing
(methods/nlp_stationary.py), and auto's CCP polish skipped after one."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
import belief_nlp.methods.nlp_engine as engine
from conftest import switching_off_more
from belief_nlp.methods import nlp_stationary


def _captured(monkeypatch, sc, ws, **kw):
    """auto's result and the arguments of its stationarity test."""
    seen = []

    def spy(*args):
        seen.append(args)
        return nlp_stationary.sensing_stationary(*args)

    monkeypatch.setattr(engine, "sensing_stationary", spy)
    res = bn.smooth(sc, ws, **kw)
    return res, seen[-1]


def _blocks(nlp, z):
    """(step, column, entries) of every column the test counts as off."""
    tri, d, K, off = nlp.info["tri"], nlp.info["d"], nlp.info["K"], nlp.info["sensing_offset"]
    t = len(tri)
    out = []
    for k in range(K):
        for j in range(d):
            ent = np.array([i for i, (_, c) in enumerate(tri) if c == j])
            if np.linalg.norm(z[off + k * t + ent]) <= nlp_stationary.OFF:
                out.append((k, j, off + k * t + ent))
    return out


def _check_blocks_by_function_values(nlp, solver, p, z, lam_g):
    """Each block's eigenvalues against the Lagrangian's second differences
    (f + lam_g^T g by function values alone, no Hessian) along its
    eigenvectors; returns the smallest eigenvalue."""
    H = solver.get_function("nlp_hess_l")(z, p, 1.0, lam_g).sparse().tocsr()
    f_g = nlp.fg

    def lag(zv):
        f, g = f_g(zv, p)
        return float(f) + float(np.dot(np.asarray(g).ravel(), lam_g))

    base, eps, worst = lag(z), 1e-4, np.inf
    blocks = _blocks(nlp, z)
    assert blocks
    for _, _, idx in blocks:
        B = H[idx][:, idx].toarray()
        w, V = np.linalg.eigh(B + B.T - np.diag(np.diag(B)))
        for lam, u in zip(w, V.T):
            zp, zm = z.copy(), z.copy()
            zp[idx] += eps * u
            zm[idx] -= eps * u
            fd = (lag(zp) - 2 * base + lag(zm)) / eps ** 2
            assert fd == pytest.approx(lam, rel=1e-3, abs=1e-5)
        worst = min(worst, w[0])
    return worst


def _warm(sc):
    return sc, bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=0, noise="per_step").path, K=20)


@pytest.fixture(scope="module")
def pm20():
    """paper-multi, planner seed 0: at alpha = 1, with the polish switching
    off up to 5x the floor, the polished answer has a negative block
    (smallest eigenvalue -0.146 measured)."""
    return _warm(bn.load_scenario("paper-multi"))


@pytest.fixture(scope="module")
def rp20():
    """random-polygons map 0: at alpha = 0.1 the polished answer is
    stationary with room to spare (smallest eigenvalue 0.094 measured)."""
    from belief_nlp.families import generate

    return _warm(generate("random-polygons", 0))


def test_the_blocks_are_the_lagrangians_curvature_by_function_values(pm20, rp20, monkeypatch):
    """Every block the test reads equals the second difference of the
    Lagrangian (function values alone) along its eigenvectors, and the
    verdict is the sign of the smallest: a negative one (sensing would
    lower the cost) on paper-multi at alpha = 1 (polish switching off up
    to 5x the floor), none on the random map."""
    verdicts = []
    for (sc, ws), alpha in ((pm20, 1.0), (rp20, 0.1)):
        with monkeypatch.context() as mp:
            if sc is pm20[0]:
                switching_off_more(mp)
            res, args = _captured(mp, sc, ws, alpha=alpha, ipopt_options={"reenter": 0})
        worst = _check_blocks_by_function_values(*args)
        verdicts.append(res.stats["ipopt"]["sensing_stationary"])
        assert verdicts[-1] == (worst >= 0.0)
    assert verdicts == [False, True]


def test_a_ccp_polish_cannot_lower_a_stationary_answer_and_auto_skips_it(pm20, rp20, monkeypatch):
    """At an answer stationary in S the CCP polish returns it (to the
    polish's tolerance): auto's default answers with IPOPT's point, and the
    explicit polish lowers it by less than 1e-5. At a non-stationary one
    (the polish switching off up to 5x the floor) the default polishes and
    gains what the explicit polish gains."""
    sc, ws = rp20
    res = bn.smooth(sc, ws, alpha=0.1)
    assert res.stats["ipopt"]["sensing_stationary"] is True
    assert res.method == "auto:ipopt" and res.stats["stages"] == ["ipopt"] and bn.verify(sc, res.path).safe
    polished = bn.smooth(sc, ws, alpha=0.1, ccp_polish=10)
    assert res.cost * (1 - 1e-5) <= polished.cost <= res.cost
    sc, ws = pm20
    switching_off_more(monkeypatch)
    # without the polish's own rounds that turn such sensing back on (test_reentry.py)
    moved = bn.smooth(sc, ws, alpha=1.0, ipopt_options={"reenter": 0})
    assert moved.stats["ipopt"]["sensing_stationary"] is False
    assert "would lower the cost" in moved.message and "would lower the cost" not in res.message
    assert moved.method == "auto:ipopt+ccp" and bn.verify(sc, moved.path).safe
    plain = bn.smooth(sc, ws, alpha=1.0, ccp_polish=0, ipopt_options={"reenter": 0})
    assert moved.cost < plain.cost * (1 - 1e-5)           # it senses where IPOPT's polish had switched off


def test_three_dimensions_and_methods_without_a_polish(monkeypatch):
    """cube3d (d = 3, columns of one step can be on and off): the blocks
    are the Lagrangian's curvature there too; a run without the polish
    reports None (nothing is claimed)."""
    sc = bn.load_scenario("cube3d")
    planned = next(p for p in (bn.plan(sc, n_nodes=300, seed=s, noise="per_step") for s in range(4)) if p.success)
    res, args = _captured(monkeypatch, sc, planned.path, K=10, alpha=1.0)
    worst = _check_blocks_by_function_values(*args)
    assert res.stats["ipopt"]["sensing_stationary"] == (worst >= 0.0)
    none = bn.smooth(sc, planned.path, K=10, alpha=1.0, method="ipopt", polish=0)
    assert none.stats["sensing_stationary"] is None


def test_one_answer_asked_again_is_not_evaluated_again(rp20, monkeypatch):
    """``_off_blocks`` keeps its last result: asked again with the same
    solver and equal arguments (copies) it hands that result back without
    a Hessian evaluation; other multipliers are evaluated afresh and equal
    a computation from scratch."""
    sc, ws = rp20
    _, args = _captured(monkeypatch, sc, ws, alpha=0.1)
    nlp, solver, p, z, lam_g = args
    first = nlp_stationary._off_blocks(nlp, solver, p, z, lam_g)
    calls = []
    real = nlp_stationary._blocks_of
    monkeypatch.setattr(nlp_stationary, "_blocks_of", lambda *a: calls.append(a) or real(*a))
    assert nlp_stationary._off_blocks(nlp, solver, np.array(p), np.array(z), np.array(lam_g)) is first
    assert not calls
    other = nlp_stationary._off_blocks(nlp, solver, p, z, 2.0 * np.asarray(lam_g))
    assert len(calls) == 1 and other is not first
    fresh = real(nlp, solver, np.asarray(p, float), np.asarray(z, float), 2.0 * np.asarray(lam_g, float))
    assert all(np.array_equal(a, b) for a, b in zip(other, fresh))
