"""The cuts of the work around the solver (docs/numerics.md, "Overhead around
the solver (session 9)") change no number: batched forms give the bits the
one-at-a-time forms gave."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
import belief_nlp.smoother.warmstart as warmstart
from belief_nlp.methods.nlp_recorder import Recorder
from belief_nlp.model import BeliefModel
from belief_nlp.model.evaluate import _hcat
from belief_nlp.model.nlp_form import build_nlp
from belief_nlp.model.nlp_matrices import _psd_factor

from conftest import paper_multi_path_pair


def test_warm_start_halvings_do_not_depend_on_the_batch(monkeypatch):
    """The halving loop checks P, P/2, P/4, ... in batches; any batch size
    (1: one candidate at a time, as before) gives the same warm start."""
    sc, path = paper_multi_path_pair(steps_per_segment=2, sensing=1e-3)
    results = []
    for batch in (1, 4, 16):
        monkeypatch.setattr(warmstart, "_HALVING_BATCH", batch)
        results.append(bn.warm_start(sc, path, K=30, verify_start=False))
    assert results[0].added_sensing > 0
    for ws in results[1:]:
        assert ws.added_sensing == results[0].added_sensing
        assert np.array_equal(ws.path.P, results[0].path.P) and np.array_equal(ws.lam, results[0].lam)


def test_stacked_psd_factor_is_the_factor_of_each_matrix():
    rng = np.random.default_rng(3)
    for d in (2, 3):
        A = rng.standard_normal((12, d, d)) * 10.0 ** rng.uniform(-6, 2, size=(12, 1, 1))
        S = A @ np.swapaxes(A, -1, -2)
        S[::3] = 0.0                              # S = 0: the jitter alone
        S[1::4] -= 1e-13 * np.eye(d)              # slightly indefinite: the PSD part
        stacked = _psd_factor(S)
        assert all(np.array_equal(stacked[k], _psd_factor(S[k])) for k in range(S.shape[0]))


def test_hcat_is_the_column_concatenation():
    M = np.arange(5 * 2 * 3, dtype=float).reshape(5, 2, 3)
    assert np.array_equal(_hcat(M), np.concatenate(list(M), axis=1))
    assert _hcat(np.zeros((0, 2, 2))).shape == (2, 0)


@pytest.fixture(scope="module")
def recorder():
    sc, path = paper_multi_path_pair(steps_per_segment=1)
    ws = bn.warm_start(sc, path)
    model = BeliefModel(sc, ws.K, 0.3)
    nlp = build_nlp(model, "logchol")
    z = model.tighten(model.from_path(ws.path, ws.lam))
    zv = nlp.pack(z)
    pv = nlp.anchor(z, 0.3)
    gv = np.asarray(ca.Function("g", [nlp.z, nlp.p], [nlp.g])(zv, pv)).ravel()
    return nlp, zv, pv, gv


def _started(nlp, pv, keep: int, keep_all: bool = True) -> Recorder:
    """A recorder at the start of an attempt (parameter pv, budget 10)."""
    rec = Recorder(nlp, keep=keep, bar=None)
    rec.keep_all_iterates = keep_all
    rec.begin(pv, 10, None)
    return rec


def test_recorder_buffers_and_dms_record_alike(recorder):
    """eval_buffer (what CasADi's nlpsol calls: the solver's buffers) and eval
    (DMs: backends outside CasADi) give the same rows, parts and candidates,
    the parts those of ``nlp.parts``; f and g passed as NULL (CasADi's Uno
    plug-in) are the NLP's own values at x."""
    nlp, zv, pv, gv = recorder
    rows = []
    for via_buffer in (True, False):
        rec = _started(nlp, pv, keep=3)
        for i in range(3):
            x = zv * (1 + 1e-3 * i)
            if via_buffer:            # a Function call on the callback goes through eval_buffer
                stop = rec(x, 1.0 + i, gv, [], [], [])
                assert float(stop) == 0.0
            else:
                assert rec.eval([ca.DM(x), ca.DM(1.0 + i), ca.DM(gv)]) == [0]
        rows.append(([r[:3] + r[4:] for r in rec.rows], [(c, it) for c, it, _ in rec.best]))
        ctrl, info, _ = nlp.parts(rec.zs[-1], pv)
        assert rec.rows[-1][5:] == (float(ctrl), float(info))
    assert rows[0] == rows[1] and len(rows[0][0]) == 2           # iteration 0 (the start) is not recorded
    rec = _started(nlp, pv, keep=3, keep_all=False)
    buf = [memoryview(np.ascontiguousarray(zv)), None, None, None, None, None]
    out = np.zeros(1)
    assert rec.eval_buffer(buf, [memoryview(out)]) == 0 and rec.eval_buffer(buf, [memoryview(out)]) == 0
    g_x = np.asarray(nlp.fg(zv, pv)[1], float).ravel()
    assert rec.rows[-1][2] == float(max(np.max(nlp.lbg - g_x, initial=0.0), np.max(g_x - nlp.ubg, initial=0.0)))
    assert rec.rows[-1][1] == float(min(np.min(g_x[:nlp.n_collision]),
                                        np.min(g_x[nlp.n_collision:nlp.n_collision + nlp.info["n_target"]])))


def test_a_recorder_keeps_only_its_best_candidates_by_default(recorder):
    """Without keep_all_iterates the iterates are not all held (every one of a
    K = 80 solve is tens of MB, kept as long as the cached solver): only the
    ``keep`` best feasible ones, the same as with them all."""
    nlp, zv, pv, gv = recorder
    gv = np.clip(gv, nlp.lbg, nlp.ubg)          # rows within their bounds: every iterate a candidate
    best = []
    for keep_all in (False, True):
        rec = _started(nlp, pv, keep=2, keep_all=keep_all)
        for i in range(6):
            rec(zv * (1 + 1e-3 * i), 1.0 - 0.01 * i, gv, [], [], [])
        assert len(rec.zs) == (5 if keep_all else 0) and len(rec.best) <= 2
        best.append([(c, it, z.tobytes()) for c, it, z in sorted(rec.best)])
    assert best[0] == best[1] and len(best[0]) == 2


# ---------------------------------------------------------------- session 16
def test_update_without_sensing_is_the_prior_and_stacks_agree():
    """belief.update returns the prior (bit for bit) where nothing is sensed,
    also through its early exit for an all-zero S, and a stack gives each
    step's own result."""
    from belief_nlp import belief
    rng = np.random.default_rng(5)
    A = rng.standard_normal((9, 2, 2))
    Pp = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(2)
    S = A[::-1] @ np.swapaxes(A[::-1], -1, -2)
    S[::2] = 0.0
    assert np.array_equal(belief.update(Pp, np.zeros_like(S)), Pp)
    assert np.array_equal(belief.update(Pp[0], np.zeros((2, 2))), Pp[0])
    stacked = belief.update(Pp, S)
    for k in range(9):
        assert np.array_equal(stacked[k], belief.update(Pp[k], S[k]))
    assert np.array_equal(stacked[::2], Pp[::2])


def test_batched_kalman_checks_equal_the_step_loop():
    """verify's Kalman and sensing checks, batched, give the per-step values
    (inf / NaN where a step cannot be evaluated), also when one prior is
    not a covariance and the batch falls back to the loop."""
    from belief_nlp import belief
    from belief_nlp._verify_kalman import kalman_checks
    sc, path = paper_multi_path_pair(steps_per_segment=2, sensing=1e-3)

    def loop(p):
        kal, smin = np.zeros(p.K), np.zeros(p.K)
        for k in range(1, p.K + 1):
            try:
                kal[k - 1] = np.linalg.norm(belief.update(p.P_prior[k], p.S[k]) - p.P[k]) / np.linalg.norm(p.P[k])
            except np.linalg.LinAlgError:
                kal[k - 1] = np.inf
            n = np.linalg.norm(p.S[k])
            smin[k - 1] = np.linalg.eigvalsh(p.S[k])[0] / n if n > 0 else 0.0
        return kal, smin

    S = path.S.copy()
    S[::3] = 0.0                              # steps that sense nothing
    mixed = bn.BeliefPath.from_sensing(path.x, path.P[0], S[1:], W=sc.W)
    for p in (path, mixed):
        kal, smin = kalman_checks(p)
        ref_kal, ref_smin = loop(p)
        np.testing.assert_allclose(kal, ref_kal, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(smin, ref_smin)
    bad = path.P_prior.copy()
    bad[3] = -np.eye(2)                       # not a covariance: the batch raises, the loop says inf there
    kal, _ = kalman_checks(dataclasses.replace(path, P_prior=bad))
    assert np.isinf(kal[2]) and np.all(np.isfinite(np.delete(kal, 2)))


def test_target_posteriors_at_the_path_nodes_are_the_path_posteriors():
    """A warm start with sensing="path" on the path's own nodes (a re-plan's)
    takes each node's posterior (the fast path), and at K = 2 x the path's
    steps the old nodes keep theirs and the new ones the smaller ellipse."""
    from belief_nlp import belief
    _, path = paper_multi_path_pair(steps_per_segment=2, sensing=1e-3)
    same = warmstart._target_posteriors(path, path.x.copy())
    assert np.array_equal(same, path.P)
    finer = warmstart.resample_means(path.x, 2 * path.K)
    out = warmstart._target_posteriors(path, finer)
    assert np.array_equal(out[::2], path.P)
    assert np.array_equal(out[1], belief.matrix_minimum(path.P[0], path.P[1]))


def test_models_share_functions_only_with_the_same_levels_and_noise():
    """BeliefModel's CasADi functions are cached by (d, F, levels, scaled W):
    a model at another collision level or noise shape gets its own (W
    scaled by a number scales the units, not the scaled problem)."""
    sc = bn.load_scenario("paper-multi")
    a, b = BeliefModel(sc, 10), BeliefModel(sc, 20, alpha=0.1)
    assert a.f_margin_inv is b.f_margin_inv and a.f_kalman is b.f_kalman
    c = BeliefModel(sc.with_options(chi2_value=2 * sc.chi2), 10)
    d = BeliefModel(sc.with_options(W=np.diag([1.0, 2.0]) @ sc.W), 10)
    assert BeliefModel(sc.with_options(W=2 * sc.W), 10).f_kalman is a.f_kalman
    assert c.f_margin_inv is not a.f_margin_inv and d.f_kalman is not a.f_kalman
    Y, Q = np.eye(2), 0.5 * np.eye(2)
    assert float(ca.norm_fro(d.f_kalman(Q, Y) - a.f_kalman(Q, Y))) > 0
