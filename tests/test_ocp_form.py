"""The stage-ordered NLP (belief_nlp.model.ocp_form) against the NLP it is
generated from: the same values, the structure fatrop needs, the same optimum."""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp
from belief_nlp.model.ocp_form import additive_terms, build_ocp, stage_labels

from conftest import paper_multi_path_pair

IPOPT = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "mu_strategy": "adaptive", "tol": 1e-8,
                                        "bound_push": 1e-4, "bound_frac": 1e-4, "constr_viol_tol": 1e-9}}


@pytest.fixture(scope="module")
def small():
    sc, path = paper_multi_path_pair(steps_per_segment=2)          # K = 10
    ws = bn.warm_start(sc, path)
    model = BeliefModel(sc, ws.K, 1.0)
    return model, model.tighten(model.from_path(ws.path, ws.lam))


def _blocks(ocp):
    """(column range, gap rows, path rows) of every stage, from N, nx, nu, ng."""
    out, col, row = [], 0, 0
    for i in range(ocp.N + 1):
        cols = (col, col + ocp.nx[i] + ocp.nu[i])
        gap = ocp.nx[i + 1] if i < ocp.N else 0
        out.append((cols, (row, row + gap), (row + gap, row + gap + ocp.ng[i])))
        col, row = cols[1], row + gap + ocp.ng[i]
    return out


def test_additive_terms_sum_back():
    x = ca.SX.sym("x", 3)
    e = 2 * (x[0] - x[1]) ** 2 - 3 * (ca.log(x[2]) + x[0] * x[1]) + 0.5 * -(x[2] ** 2) + 4.0
    terms = additive_terms(e)
    assert len(terms) == 5
    f = ca.Function("f", [x], [e - sum(terms)])
    for v in ([1.0, 2.0, 3.0], [0.3, -1.2, 0.7]):
        assert abs(float(f(v))) < 1e-12


def test_additive_terms_open_products_with_parameters():
    """Given the variables, a product with a factor free of them (a parameter
    such as alpha) is opened and the factor kept on every term."""
    x, a = ca.SX.sym("x", 2), ca.SX.sym("a")
    e = x[0] ** 2 + a * (0.5 * (ca.log(x[1]) - x[0] * x[1]))
    assert len(additive_terms(e)) == 2                  # a * (...) is one term without z
    terms = additive_terms(e, x)
    assert len(terms) == 3 and sum(ca.depends_on(t, a) for t in terms) == 2
    f = ca.Function("f", [x, a], [e - sum(terms)])
    for v, av in (([1.0, 2.0], 0.3), ([0.3, 1.7], -2.0)):
        assert abs(float(f(v, av))) < 1e-12


@pytest.mark.parametrize("formulation", ["logchol", "cholesky", "minors"])
def test_same_values_and_fatrop_structure(small, formulation):
    """At the warm start the stage form's cost equals the NLP's, its source rows
    the NLP's rows, its gap rows vanish; the Jacobian has fatrop's block
    pattern (gap rows: the stage's columns plus an identity on the next
    state; other rows: their stage's columns) and the Lagrangian Hessian is
    block diagonal by stage."""
    model, z = small
    nlp = build_nlp(model, formulation, floor=1e-9)
    ocp = build_ocp(nlp)
    K = model.data.K
    assert ocp.N == K - 1 and ocp.nx[0] == 0 and sum(ocp.nu) == nlp.z.shape[0]
    assert ocp.z.shape[0] == sum(ocp.nx) + sum(ocp.nu) and ocp.g.shape[0] == sum(ocp.nx[1:]) + sum(ocp.ng)
    pv = nlp.anchor(z)
    f_n, g_n = ca.Function("n", [nlp.z, nlp.p], [nlp.f, nlp.g])(nlp.pack(z), pv)
    f_o, g_o = ca.Function("o", [ocp.z, ocp.p], [ocp.f, ocp.g])(ocp.pack(z), pv)
    assert float(f_o) == pytest.approx(float(f_n), rel=1e-12)
    g_o = g_o.full().ravel()
    np.testing.assert_allclose(ocp.source_g(g_o), g_n.full().ravel(), rtol=1e-12, atol=1e-12)
    assert np.all(np.delete(g_o, ocp.source_rows) == 0.0)
    np.testing.assert_array_equal(ocp.to_source(ocp.pack(z)), nlp.pack(z))
    # Jacobian pattern
    Jac = np.array(ca.DM(ca.jacobian_sparsity(ocp.g, ocp.z), 1).full(), bool)
    blocks = _blocks(ocp)
    for i, ((c0, c1), (r0, r1), (p0, p1)) in enumerate(blocks):
        assert not Jac[p0:p1, :c0].any() and not Jac[p0:p1, c1:].any()
        if r1 > r0:
            nxt = blocks[i + 1][0][0]
            J = ca.Function("j", [ocp.z, ocp.p], [ca.jacobian(ocp.g[r0:r1], ocp.z)])(ocp.pack(z), pv).full()
            np.testing.assert_array_equal(J[:, nxt:nxt + (r1 - r0)], np.eye(r1 - r0))
            assert not Jac[r0:r1, :c0].any() and not Jac[r0:r1, nxt + (r1 - r0):].any()
    # Hessian of the Lagrangian: block diagonal by stage
    lam = ca.SX.sym("lam", ocp.g.shape[0])
    H = np.array(ca.DM(ca.hessian(ocp.f + ca.dot(lam, ocp.g), ocp.z)[0].sparsity(), 1).full(), bool)
    mask = np.zeros_like(H)
    for (c0, c1), _, _ in blocks:
        mask[c0:c1, c0:c1] = True
    assert not (H & ~mask).any()


def test_same_optimum_as_the_nlp(small):
    """IPOPT on both forms from the same start: the same optimum (cost and
    point), the stage form read back into the NLP's variables."""
    model, z = small
    nlp = build_nlp(model, "logchol")
    ocp = build_ocp(nlp)
    pv = nlp.anchor(z)
    sols = []
    for prob in (nlp, ocp):
        S = ca.nlpsol("s", "ipopt", {"x": prob.z, "p": prob.p, "f": prob.f, "g": prob.g}, IPOPT)
        r = S(x0=prob.pack(z), p=pv, lbx=prob.lbz, ubx=prob.ubz, lbg=prob.lbg, ubg=prob.ubg)
        assert S.stats()["success"]
        sols.append(r)
    assert float(sols[1]["f"]) == pytest.approx(float(sols[0]["f"]), rel=1e-7)
    x_n, x_o = sols[0]["x"].full().ravel(), ocp.to_source(sols[1]["x"].full())
    assert np.max(np.abs(x_o - x_n)) <= 1e-4 * max(1.0, np.max(np.abs(x_n)))
    a, b = nlp.unpack(x_n), ocp.unpack(sols[1]["x"].full())
    assert model.cost(b)[0] == pytest.approx(model.cost(a)[0], rel=1e-7)


def test_a_variable_added_later_lands_in_its_step(small):
    """A per-step variable appended to the NLP without a label (as a per-pair
    confidence level would be) is placed in the step of the rows that read it,
    and the optimum of the extended NLP is unchanged by the reordering."""
    model, z = small
    nlp = build_nlp(model, "logchol")
    K, d = model.data.K, model.data.d
    tau = ca.SX.sym("tau", K)
    X = nlp.z[:d * K].reshape((d, K))
    # tau_k >= x_k[0] - 1 (reads step k) and a small cost on tau
    g = ca.vertcat(nlp.g, tau - X[0, :].T)
    f = nlp.f + 1e-3 * ca.sumsqr(tau)
    z_ext, n0 = ca.vertcat(nlp.z, tau), nlp.z.shape[0]
    parts = ca.Function("parts", [z_ext, nlp.p], nlp.parts(z_ext[:n0], nlp.p))
    start = ca.SX.sym("start", nlp.margins.size1_in(1))
    margins = ca.Function("margins", [z_ext, start], nlp.margins(z_ext[:n0], start))
    ext = replace(nlp, z=z_ext, g=g, f=f, parts=parts, margins=margins, lbz=np.r_[nlp.lbz, -np.full(K, np.inf)],
                  ubz=np.r_[nlp.ubz, np.full(K, np.inf)], lbg=np.r_[nlp.lbg, np.full(K, -1.0)],
                  ubg=np.r_[nlp.ubg, np.full(K, np.inf)])
    assert np.all(stage_labels(ext)[-K:] == -1)
    ocp = build_ocp(ext)
    lab = ocp.info["stages_of_source"]
    np.testing.assert_array_equal(lab[-K:], np.arange(1, K + 1))
    pv = nlp.anchor(z)
    z0 = np.r_[nlp.pack(z), z.x[1:, 0]]
    fs = []
    for prob, x0 in ((ext, z0), (ocp, z0[ocp.src])):
        S = ca.nlpsol("s", "ipopt", {"x": prob.z, "p": prob.p, "f": prob.f, "g": prob.g}, IPOPT)
        r = S(x0=x0, p=pv, lbx=prob.lbz, ubx=prob.ubz, lbg=prob.lbg, ubg=prob.ubg)
        assert S.stats()["success"]
        fs.append(float(r["f"]))
    assert fs[1] == pytest.approx(fs[0], rel=1e-7)
    assert fs[0] < float(ca.Function("f", [ext.z, ext.p], [ext.f])(z0, pv))


def test_a_row_across_three_steps_is_refused(small):
    """Not a sum of per-step terms: no running sum can carry it."""
    model, _ = small
    nlp = build_nlp(model, "logchol")
    d = model.data.d
    bad = replace(nlp, g=ca.vertcat(nlp.g, nlp.z[0] * nlp.z[2 * d]), lbg=np.r_[nlp.lbg, 0.0], ubg=np.r_[nlp.ubg, 1.0])
    with pytest.raises(ValidationError, match="neighbours"):
        build_ocp(bad)
    with pytest.raises(ValidationError, match="neighbours"):
        build_ocp(build_nlp(model, "eliminated"))


def test_a_row_over_every_step_becomes_a_running_sum(small):
    """A row summing per-step terms over the whole path (as a risk budget's
    sum_kj g(tau_kj) <= Delta does) becomes running sums r_k = r_{k-1} +
    (step k's terms), each row of one stage and its neighbour: the source row
    is r_K, the new rows vanish at a packed point, the Jacobian keeps
    fatrop's block pattern, and the optimum with the row active is the
    NLP's (IPOPT on both forms)."""
    model, z = small
    nlp = build_nlp(model, "logchol")
    K, d = model.data.K, model.data.d
    X = nlp.z[:d * K].reshape((d, K))
    row = ca.sum1((X[0, :].T - 0.5) ** 2) / 4.0           # every step; opened through the division
    pv = nlp.anchor(z)
    at_start = float(ca.Function("r", [nlp.z], [row])(nlp.pack(z)))
    ext = replace(nlp, g=ca.vertcat(nlp.g, row), lbg=np.r_[nlp.lbg, -np.inf], ubg=np.r_[nlp.ubg, 0.9 * at_start])
    ocp = build_ocp(ext)
    assert ocp.info["n_running_sums"] == K and ocp.z.shape[0] == sum(ocp.nx) + sum(ocp.nu)
    g_n = ca.Function("n", [ext.z, ext.p], [ext.g])(ext.pack(z), pv).full().ravel()
    g_o = ca.Function("o", [ocp.z, ocp.p], [ocp.g])(ocp.pack(z), pv).full().ravel()
    np.testing.assert_allclose(ocp.source_g(g_o), g_n, rtol=1e-12, atol=1e-12)
    assert g_n[-1] == pytest.approx(at_start, rel=1e-12)
    np.testing.assert_allclose(np.delete(g_o, ocp.source_rows), 0.0, atol=1e-12)
    Jac = np.array(ca.DM(ca.jacobian_sparsity(ocp.g, ocp.z), 1).full(), bool)
    for i, ((c0, c1), (r0, r1), (p0, p1)) in enumerate(_blocks(ocp)):
        assert not Jac[p0:p1, :c0].any() and not Jac[p0:p1, c1:].any()
    fs, xs = [], []
    for prob in (ext, ocp):
        S = ca.nlpsol("s", "ipopt", {"x": prob.z, "p": prob.p, "f": prob.f, "g": prob.g}, IPOPT)
        r = S(x0=prob.pack(z), p=pv, lbx=prob.lbz, ubx=prob.ubz, lbg=prob.lbg, ubg=prob.ubg)
        assert S.stats()["success"]
        fs.append(float(r["f"]))
        xs.append(r["x"].full().ravel())
    assert fs[1] == pytest.approx(fs[0], rel=1e-7)
    x_o = ocp.to_source(xs[1])
    assert float(ca.Function("r", [nlp.z], [row])(x_o)) == pytest.approx(0.9 * at_start, rel=1e-6)   # active
    f_free = float(ca.Function("f", [nlp.z, nlp.p], [nlp.f])(nlp.pack(z), pv))
    assert fs[0] < f_free
