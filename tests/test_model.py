"""The one symbolic model and every form derived from it, at random points.

* the exact margins of the model agree with the independent geometry
  (Theorem 1: a certificate value never exceeds the exact clearance, and the
  optimal certificate attains it);
* the convexified program (the CCP step) majorises the exact DOC program and
  is tight at its point of linearisation (CCP's two requirements);
* the CVXPY problem generated from the model evaluates to the model's own
  cone entries at random z (the generated form is the model);
* the NLP's rows are the model's margins at random points.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import geometry
from belief_nlp.methods.ccp import compiled_step, initial_rho
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import FORMULATIONS, build_nlp

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def start():
    sc, path = paper_multi_path_pair(steps_per_segment=2)      # K = 10
    ws = bn.warm_start(sc, path)
    model = BeliefModel(sc, ws.K, 1.0)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    return sc, ws, model, z


def _perturb(model, z, rng, scale):
    """A nearby point: means moved, sensing changed by a random PSD amount,
    certificates scaled; priors re-derived (Kalman-consistent)."""
    out = z.copy()
    out.x[1:] += scale * rng.normal(size=out.x[1:].shape)
    G = rng.normal(size=out.S.shape)
    out.S[1:] = out.S[1:] + scale * (G @ np.swapaxes(G, -1, -2))[1:]
    out.lam = out.lam * np.exp(scale * rng.normal(size=out.lam.shape))
    return model.tighten(out)


def test_model_cost_is_the_paths_objective(start):
    sc, ws, model, z = start
    rng = np.random.default_rng(0)
    for _ in range(5):
        p = _perturb(model, z, rng, 0.05)
        total, ctrl, info = model.cost(p)
        path = model.to_path(p)
        assert ctrl == pytest.approx(path.control_cost, rel=1e-10)
        assert total == pytest.approx(path.steering_cost(model.data.alpha), rel=1e-9)


def test_margins_are_theorem1_lower_bounds_attained_by_the_optimal_certificate(start):
    """For ANY lam >= 0, min(start margin, end margin) <= exact clearance - chi2
    (scaled: the model's margins are in units where W ~ I, the clearance is
    scale-free); with the geometry's optimal certificate both are equal."""
    sc, ws, model, z = start
    D = model.data
    rng = np.random.default_rng(1)
    hz = geometry.PolytopeSet.build(sc.hazards)
    for trial in range(4):
        p = _perturb(model, z, rng, 0.03)
        path = model.to_path(p)
        exact = geometry.transition_minimiser(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise, hz,
                                              want_lam=True)
        gap = exact.dist2 - D.chi2                                       # (K, J)
        p.lam = np.abs(rng.normal(size=p.lam.shape)) * 10 * D.face_mask   # random certificates
        s, e = model.transition_margins(p)
        assert np.all(np.minimum(s, e) <= gap + 1e-9 * (1 + np.abs(gap)))
        p.lam = exact.lam * D.sigma                                      # optimal ones
        s, e = model.transition_margins(p)
        np.testing.assert_allclose(np.minimum(s, e), gap, rtol=1e-6, atol=1e-6)
    # target margins against the geometry's containment margins (metres)
    tgt = model.target_margins(z) * D.sigma
    T = sc.target
    ref = geometry.containment_margins(ws.path.x[-1], ws.path.P[-1], T.A, T.b, sc.chi2)
    np.testing.assert_allclose(np.sort(tgt), np.sort(np.ravel(ref)), rtol=1e-8, atol=1e-12)


def _family_value(kind, dim, batch, e):
    """Per cone, how far inside it the entries are (>= 0 inside)."""
    if kind == "psd":
        return np.linalg.eigvalsh(e.reshape(batch, dim, dim))[:, 0]
    if kind == "soc":
        E = e.reshape(batch, dim)
        return E[:, 0] - np.linalg.norm(E[:, 1:], axis=1)
    if kind == "exp":
        E = e.reshape(batch, 3)
        return E[:, 2] - E[:, 1] * np.exp(E[:, 0] / E[:, 1])
    return e


def _h2_exact_and_convex(model, form, zv, pv, point):
    """(exact h2, convexified h2) at z for every end: the exact h2 uses the
    bilinear term itself, the convexified one is read back from the rotated
    SOC entries (w = (t + s) / sqrt 2, 1/2 ||y||^2)."""
    from belief_nlp.model import terms

    D = model.data
    B = form.layout.blocks
    new = form.layout.extract(zv, point)
    new.lam = np.where(B.lam >= 0, zv[np.maximum(B.lam, 0)], 0.0)      # raw, not projected on lam >= 0
    out = {}
    for name, end in (("h2_end", True), ("h2_start", False)):
        fam = next(f for f in form.families if f.name == name)
        e = np.asarray(ca.Function("e", [form.z, form.p], [fam.expr])(zv, pv)).ravel().reshape(fam.batch, fam.dim)
        w = (e[:, 0] + e[:, -1]) / np.sqrt(2)
        convex = -(w - 0.5 * np.sum(e[:, 1:-1] ** 2, axis=1))      # h2 majorant = 1/2||y||^2 - w
        ks = range(1, D.K + 1) if end else range(2, D.K + 1)
        exact = []
        for k in ks:
            for j in range(D.J):
                R = zv[B.R_end[k - 1, j] if end else B.R_start[k - 1, j]]
                x = new.x[k] if end else new.x[k - 1]
                exact.append(float(terms.h2(R, new.lam[k - 1, j], x, D.A[j], D.b[j], form.chi2)))
        out[name] = (np.array(exact), convex)
    return out


def test_convex_step_majorises_the_doc_program_and_is_tight_at_its_point(start):
    sc, ws, model, z = start
    form = model.convex_form
    rho = initial_rho(model, z)
    pv = form.layout.params(z, rho, rho)
    z0 = form.layout.point_vector(z)
    f_obj = ca.Function("f", [form.z, form.p], [form.objective])
    # tight at the point: every family feasible, h2 majorant = exact h2, objective = exact cost
    for name, (exact, convex) in _h2_exact_and_convex(model, form, z0, pv, z).items():
        np.testing.assert_allclose(convex, exact, rtol=1e-9, atol=1e-9)
    for fam in form.families:
        e = np.asarray(ca.Function("e", [form.z, form.p], [fam.expr])(z0, pv)).ravel()
        assert np.min(_family_value(fam.kind, fam.dim, fam.batch, e)) >= -1e-9, fam.name
    cost0 = model.cost(z)[0]
    sigma2 = model.data.sigma ** 2
    # the conic objective is the cost minus constants of the point: compare differences
    rng = np.random.default_rng(2)
    for _ in range(6):
        zr = z0 + 1e-2 * rng.normal(size=z0.shape) * (np.abs(z0) + 1e-2)
        for name, (exact, convex) in _h2_exact_and_convex(model, form, zr, pv, z).items():
            assert np.all(convex >= exact - 1e-9 * (1 + np.abs(exact))), name
    # objective: tangent of the concave log det is an upper bound -> majorant of the exact cost
    for _ in range(4):
        q = _perturb(model, z, rng, 0.02)
        zq = form.layout.point_vector(q)
        zq[form.layout.blocks.x[1:].ravel()] = (q.x[1:] - z.x[1:]).ravel()
        gap_model = float(f_obj(zq, pv) - f_obj(z0, pv))
        gap_exact = model.cost(q)[0] - cost0
        assert gap_model >= gap_exact - 1e-9 * (1 + abs(gap_exact))
    assert sigma2 > 0


def test_generated_cvxpy_problem_equals_the_model_at_random_points(start):
    """Each CVXPY constraint's expression, evaluated at random z with the
    parameters of a random point, equals the model family's entries."""
    sc, ws, model, z = start
    step, _, _ = compiled_step(model)
    form = model.convex_form
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = _perturb(model, z, rng, 0.02)
        rho = initial_rho(model, q) * np.exp(rng.normal(size=(model.data.K, model.data.J)))
        step.set_point(q, rho, rho * 2)
        pv = form.layout.params(q, rho, rho * 2)
        zr = rng.normal(size=step.layout.blocks.n)
        step.z.value = zr
        for fam in form.families:
            ref = np.asarray(ca.Function("e", [form.z, form.p], [fam.expr])(zr, pv)).ravel()
            con = step.constraints[fam.name]
            got = np.concatenate([np.ravel(a.value, order="C") for a in con.args]) if fam.kind != "soc" else \
                np.column_stack([con.args[0].value, con.args[1].value]).ravel()
            if fam.kind == "exp":
                got = np.column_stack([a.value for a in con.args]).ravel()
            np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9, err_msg=fam.name)
    assert step.problem.is_dpp()


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_nlp_rows_are_the_model_margins_at_random_points(start, formulation):
    sc, ws, model, z = start
    nlp = build_nlp(model, formulation, floor=1e-9)    # logchol: a floor below every point's sensing
    rng = np.random.default_rng(4)
    for _ in range(3):
        q = _perturb(model, z, rng, 0.05)
        zv = nlp.pack(q)
        col, tgt = nlp.margin_values(zv)
        s, e = model.transition_margins(q)
        np.testing.assert_allclose(col, np.stack([s, e], axis=-1).ravel(), rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(tgt, model.target_margins(q), rtol=1e-8, atol=1e-9)
        ctrl, info, _ = (float(v) for v in nlp.parts(zv, nlp.anchor(q)))
        total, c_ref, i_ref = model.cost(q)
        assert ctrl == pytest.approx(c_ref, rel=1e-9) and info == pytest.approx(i_ref, rel=1e-7)


def test_exported_mpc_functions_equal_the_model_at_random_points(start):
    """export.py (SI units, covariance form) and the model (scaled units,
    information form) evaluate the same terms: their margins agree after the
    change of units (x' = x / sigma, P' = P / sigma^2, lam' = sigma lam)."""
    from belief_nlp import export

    sc, ws, model, z = start
    D = model.data
    s = D.sigma
    fns = export.export_functions(sc)
    rng = np.random.default_rng(5)
    for _ in range(20):
        j = int(rng.integers(D.J))
        h = sc.hazards[j]
        x0, x1 = rng.uniform(0, 1, 2), rng.uniform(0, 1, 2)
        G = rng.normal(size=(2, 2))
        P = 1e-3 * (G @ G.T) + 1e-6 * np.eye(2)
        lam = np.abs(rng.normal(size=h.n_faces)) * 30
        m0, m1 = (float(v) for v in fns[f"transition_{export._slug(h.name)}"](x0, P, x1, sc.W, lam))
        lam_s = np.zeros(D.F)
        lam_s[: h.n_faces] = lam * s
        ref0 = float(model.f_margin_cov(x0 / s, P / s**2, lam_s, D.A[j], D.b[j]))
        ref1 = float(model.f_margin_inv(x1 / s, np.linalg.inv((P + sc.W) / s**2), lam_s, D.A[j], D.b[j]))
        assert m0 == pytest.approx(ref0, rel=1e-9, abs=1e-9) and m1 == pytest.approx(ref1, rel=1e-7, abs=1e-7)
        # information cost and update: the model's information(Y, Q) with Q = P_hat^-1
        S = 1e3 * np.abs(rng.normal()) * np.eye(2)
        Ph = P + sc.W
        nats = float(fns["information_cost"](Ph, S))
        _, info = model.f_step(x0, x0, np.linalg.inv(Ph) * s**2 + S * s**2, np.linalg.inv(Ph) * s**2)
        assert nats == pytest.approx(float(info), rel=1e-9)
    # target containment (metres) against the model's margin (scaled length)
    x = np.array([0.65, 0.05])
    P = 1e-5 * np.eye(2)
    got = np.asarray(fns["target_containment"](x, P)).ravel()
    ref = np.array([float(model.f_target(x / s, np.linalg.inv(P / s**2), D.At[n], D.bt[n]))
                    for n in range(D.At.shape[0])]) * s
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)


def test_one_compiled_step_serves_every_alpha(start):
    """alpha is the step's last parameter: the CVXPY step and the Clarabel
    data compiled for one alpha, re-used (from memory) for another, give the
    objective of the convex form built for that other alpha from scratch
    (differences between random z, so constants cancel)."""
    from belief_nlp.methods.ccp import conic_step_of
    from belief_nlp.model.cache import MEMORY
    from belief_nlp.model.doc import convex_form

    sc, ws, model, z = start
    MEMORY.clear()
    compiled_step(model)
    conic_step_of(model)
    other = BeliefModel(sc, model.data.K, 0.37)
    step, origin, _ = compiled_step(other)
    conic = conic_step_of(other)
    assert origin == "memory" and step.layout.data.alpha == conic.layout.data.alpha == 0.37
    fresh = convex_form(other.data)
    f_obj = ca.Function("f", [fresh.z, fresh.p], [fresh.objective])
    rng = np.random.default_rng(5)
    q = _perturb(other, z, rng, 0.02)
    rho = initial_rho(other, q)
    step.set_point(q, rho, rho)
    pv = fresh.layout.params(q, rho, rho)
    assert pv[-1] == 0.37
    _, _, qc = conic.data(q, rho, rho)
    z1, z2 = rng.normal(size=(2, step.layout.blocks.n))
    ref = float(f_obj(z1, pv) - f_obj(z2, pv))
    values = []
    for zr in (z1, z2):
        step.z.value = zr
        values.append(float(step.problem.objective.value))
    assert values[0] - values[1] == pytest.approx(ref, rel=1e-9, abs=1e-9)
    H = (conic.P + conic.P.T).toarray() - np.diag(conic.P.diagonal())    # Clarabel's P: the upper triangle
    quad = [0.5 * zr @ (H @ zr) + qc @ zr for zr in (z1, z2)]
    assert quad[0] - quad[1] == pytest.approx(ref, rel=1e-9, abs=1e-9)
    # and the model's own alpha is untouched by the other's use
    assert compiled_step(model)[0].layout.data.alpha == model.data.alpha
