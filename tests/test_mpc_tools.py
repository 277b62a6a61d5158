"""The MPC adapters with the real tools (do-mpc, rockit; acados when built):
closed loops on paper-multi that reach the target and verify, and the
inside-obstacle property through every adapter's installed constraints."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import export, geometry

RNG = np.random.default_rng(5)
TOOL_MODULES = {"dompc": "do_mpc", "rockit": "rockit"}


@pytest.fixture(scope="module")
def kit():
    """The MPC layout of paper-multi (its scenario: ``kit.scenario``)."""
    return export.BeliefMPC.build("paper-multi")


@pytest.fixture(scope="module")
def multi(kit):
    return kit.scenario


def _certified(sc, path) -> None:
    """Every applied transition clears every hazard exactly (Theorem 1), the
    last belief lies in the target, and bn.verify agrees."""
    hazards = geometry.PolytopeSet.build(sc.hazards)
    for k in range(path.K):
        c = geometry.transition_clearances(path.x[k][None], path.P[k][None], path.x[k + 1][None], sc.W, hazards,
                                           sc.chi2)
        assert float(np.min(c)) >= 0, f"step {k + 1} is not certified"
    assert float(np.min(geometry.containment_margin(path.x[-1], path.P[-1], sc.target.A, sc.target.b,
                                                    sc.chi2))) >= 0
    report = bn.verify(sc, path)
    assert report.safe, report.summary()
    assert sc.target.contains(path.x[-1])


@pytest.mark.parametrize("tool", ["dompc", "rockit"])
def test_closed_loop_of_20_steps_reaches_the_target_safely(multi, tool):
    """~10 s each (warm-started, ~10 IPOPT iterations a step): in the default run."""
    pytest.importorskip(TOOL_MODULES[tool])
    path = export.closed_loop(multi, tool, horizon=10, steps=20)
    assert path.K == 20 and path.meta["tool"] == tool and len(path.meta["step_times"]) == 20
    _certified(multi, path)


def _inside(multi, kit):
    """(state, inputs) of a belief at obstacle 1's centroid (P = 1e-6 I) with
    random certificates, negative ones included."""
    c = multi.obstacles[0].vertices.mean(axis=0)
    s = kit.state(c, 1e-6 * np.eye(2))
    for _ in range(100):
        lam = RNG.normal(scale=10 ** RNG.uniform(-1, 4), size=kit.stage.n_lam)
        yield s, kit.input(c, c, np.zeros((2, 2)), lam * kit.sigma)


def test_inside_an_obstacle_is_infeasible_in_opti(multi, kit):
    from belief_nlp.export.opti import OptiMPC

    mpc = OptiMPC(kit, horizon=1)
    o = mpc.opti
    for s, v in _inside(multi, kit):
        fix = [mpc.V == v, mpc.s0 == s, mpc.gate == np.array([[1.0], [0.0]])]
        g, lbg = np.asarray(o.value(o.g, fix)).ravel(), np.asarray(o.value(o.lbg, fix)).ravel()
        assert np.any(g < lbg)


def test_inside_an_obstacle_is_infeasible_in_dompc(multi, kit):
    pytest.importorskip("do_mpc")
    from belief_nlp.export.dompc import dompc_model

    m = dompc_model(kit)
    from belief_nlp.export.dompc import dompc_controller

    mpc = dompc_controller(kit, m, 2, lambda tpl, t: tpl)
    (cons,) = [c for c in mpc.nl_cons_list if c["expr_name"] == "belief_safety"]
    f = ca.Function("nl", [m.x["s"], m.u["v"], m.tvp["gate"], m.tvp["p"], m.tvp["p_t"]], [cons["expr"]])
    for s, v in _inside(multi, kit):
        expr = np.asarray(f(s, v, [1, 0], kit.stage.params(), kit.terminal.params())).ravel()
        assert np.any(expr > np.ravel(cons["ub"]))                 # do-mpc: expr <= ub


def test_inside_an_obstacle_is_infeasible_in_rockit(multi, kit):
    pytest.importorskip("rockit")
    from belief_nlp.export.rockit import rockit_ocp

    _, sym = rockit_ocp(kit, 2)
    f = ca.Function("rows", [sym[k] for k in ("s", "v", "gate", "p", "p_t")], [sym["rows"]])
    for s, v in _inside(multi, kit):
        g = np.asarray(f(s, v, [1, 0], kit.stage.params(), kit.terminal.params())).ravel()
        assert np.any(g < kit.lbg)


def test_inside_an_obstacle_is_infeasible_in_the_acados_formulation(multi, kit):
    from belief_nlp.export.acados import acados_formulation, stage_parameters

    f = acados_formulation(kit)
    h = ca.Function("h", [f["x"], f["u"], f["p"]], [f["con_h_expr"]])
    p = stage_parameters(kit, [1, 0], np.zeros(kit.n_ref))
    for s, v in _inside(multi, kit):
        assert np.any(np.asarray(h(s, v, p)).ravel() < f["lh"])


def test_acados_formulation_terminal_part_and_units(multi, kit):
    from belief_nlp.export.acados import acados_formulation, stage_parameters

    f = acados_formulation(kit)
    assert f["con_h_expr"].shape[0] == f["lh"].size == f["uh"].size == kit.lbg.size
    assert f["con_h_expr_e"].shape[0] == f["lh_e"].size == kit.terminal.lbg.size
    he = ca.Function("he", [f["x"], f["p"]], [f["con_h_expr_e"]])
    far = kit.state(multi.x0, multi.P0)
    ref = np.zeros(kit.n_ref)
    off = np.asarray(he(far, stage_parameters(kit, [1, 0], ref))).ravel()
    on = np.asarray(he(far, stage_parameters(kit, [1, 1], ref))).ravel()
    assert np.all(off >= f["lh_e"]) and np.any(on < f["lh_e"])      # the start is not in the target
    centre = multi.target.vertices.mean(axis=0) if hasattr(multi.target, "vertices") else None
    if centre is not None:
        inside = np.asarray(he(kit.state(centre, 1e-8 * np.eye(2)), stage_parameters(kit, [1, 1], ref))).ravel()
        assert np.all(inside >= f["lh_e"])


def test_acados_ocp_builds():
    pytest.importorskip("acados_template", reason="acados is not on PyPI: build it from source "
                                                  "(https://docs.acados.org/installation/, docs/mpc.md) to run this test")
    from belief_nlp.export.acados import acados_ocp

    kit = export.BeliefMPC.build("paper-multi")
    ocp = acados_ocp(kit, horizon=10)
    assert ocp.model.con_h_expr.shape[0] == ocp.constraints.lh.size == kit.lbg.size
    assert ocp.model.con_h_expr_e.shape[0] == ocp.constraints.lh_e.size == kit.terminal.lbg.size
    assert ocp.constraints.x0.size == kit.nx


def test_make_solver_names_the_tools(kit):
    with pytest.raises(bn.errors.ValidationError):
        export.closed_loop("paper-multi", "nope", steps=2)
    assert set(export.TOOLS) == {"opti", "dompc", "rockit"}
