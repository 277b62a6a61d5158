"""Method "ipopt" with the means scaled in its log-Cholesky stage
(option ``scale_means``, belief_nlp.methods.nlp_scaled)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods.nlp_scaled import scaled
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp

# hand_start (K = 20), small_start (K = 10) and ipopt_from: tests/conftest.py


def test_scaled_nlp_is_the_same_problem(small_start):
    """In y = z / D the objective, rows, bounds and cost parts at a point are
    the unscaled NLP's at z = D y; packing and unpacking give the same layout."""
    sc, ws = small_start
    model = BeliefModel(sc, ws.K, 0.4)
    lay = model.tighten(model.from_path(ws.path, ws.lam))
    nlp = build_nlp(model, "logchol")
    sn = scaled(nlp, 100.0)
    D = sn.info["variable_scale"]
    nX = nlp.info["sensing_offset"]
    assert np.all(D[:nX] == 100.0) and np.all(D[nX:] == 1.0)
    z, y = nlp.pack(lay), sn.pack(lay)
    np.testing.assert_allclose(y * D, z, rtol=1e-15, atol=0)
    p = nlp.anchor(lay)
    fz = ca.Function("fz", [nlp.z, nlp.p], [nlp.f, nlp.g])
    fy = ca.Function("fy", [sn.z, sn.p], [sn.f, sn.g])
    (f0, g0), (f1, g1) = fz(z, p), fy(y, p)
    assert float(f1) == pytest.approx(float(f0), rel=1e-12)
    np.testing.assert_allclose(np.asarray(g1), np.asarray(g0), rtol=1e-10, atol=1e-12)
    for a, b in zip(sn.parts(y, p), nlp.parts(z, p)):
        assert float(a) == pytest.approx(float(b), rel=1e-12, abs=1e-15)
    back = sn.unpack(y)
    np.testing.assert_allclose(back.x, lay.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.isfinite(sn.lbz), np.isfinite(nlp.lbz))
    fin = np.isfinite(nlp.lbz)
    np.testing.assert_allclose(sn.lbz[fin] * D[fin], nlp.lbz[fin], rtol=1e-15)


@pytest.mark.parametrize("alpha", [0.1, 1.0])
def test_scaled_means_answer_is_verified_and_not_costlier(hand_start, ipopt_from, alpha):
    """K = 20, paper-multi: the same local optimum as the unscaled stage (to
    1e-6 relative) or a lower one, exactly safe; the polish follows it."""
    sc, ws = hand_start
    ref = ipopt_from(hand_start, alpha)
    res = bn.smooth(sc, ws, method="ipopt", alpha=alpha, scale_means=100.0)
    assert res.status == "converged" and res.safe and bn.verify(sc, res.path).safe
    assert res.cost <= ref.cost * (1 + 1e-6)
    assert res.stats["attempts"][0]["formulation"] == "logchol"
    assert res.stats["attempts"][0]["return_status"] == "Solve_Succeeded"
    assert res.stats["attempts"][-1]["formulation"] == "cholesky"
    assert len(res.history) == res.nit + 1


def test_scaled_solver_is_cached(small_start):
    sc, ws = small_start
    from belief_nlp.methods.ipopt import clear_cache

    clear_cache()
    first = bn.smooth(sc, ws, method="ipopt", alpha=0.5, scale_means=30.0)
    again = bn.smooth(sc, ws, method="ipopt", alpha=0.5, scale_means=30.0)
    assert first.stats["build"].startswith("built") and again.stats["build"] == "memory"
    assert again.cost == first.cost and again.nit == first.nit
    # scale 1 is the unscaled NLP itself
    plain = bn.smooth(sc, ws, method="ipopt", alpha=0.5, scale_means=1.0)
    default = bn.smooth(sc, ws, method="ipopt", alpha=0.5)
    assert plain.cost == default.cost and plain.nit == default.nit


@pytest.mark.parametrize("bad", [0, -1.0, float("inf"), float("nan"), True, "10"])
def test_bad_scale_means(small_start, bad):
    sc, ws = small_start
    with pytest.raises(ValidationError, match="scale_means"):
        bn.smooth(sc, ws, method="ipopt", scale_means=bad)
    with pytest.raises(ValidationError, match="ipopt_options"):
        bn.smooth(sc, ws, method="auto", ipopt_options={"scale_means": bad})


def test_auto_passes_scale_means(small_start):
    sc, ws = small_start
    res = bn.smooth(sc, ws, method="auto", alpha=1.0, ipopt_options={"scale_means": 100.0})
    assert res.success and bn.verify(sc, res.path).safe
    assert res.stats["ipopt"]["build"].startswith("built") or res.stats["ipopt"]["build"] == "memory"

