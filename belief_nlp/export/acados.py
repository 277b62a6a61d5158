"""Adapter for acados: the belief layout of :mod:`.kit` as an ``AcadosOcp`` formulation.

acados is not on PyPI; build it from source (https://docs.acados.org/installation/)
and install its ``acados_template`` Python package. :func:`acados_formulation`
needs only CasADi (it is what gets installed, testable anywhere);
:func:`acados_ocp` fills an ``AcadosOcp`` from it::

    kit = BeliefMPC.build("paper-multi")
    ocp = acados_ocp(kit, horizon=10)                # AcadosOcp: model, cost, constraints, options
    solver = AcadosOcpSolver(ocp)                    # acados generates and compiles C
    for k in range(10):
        solver.set(k, "p", stage_parameters(kit, gate[:, k], ref[:, k]))
    ...

Formulation (discrete dynamics, external cost, nonlinear path and terminal
constraints):

* ``x = s`` (kit.nx), ``u = v`` (kit.nu), ``disc_dyn_expr = kit.step(s, v)``;
* stage parameters ``p = (gate, ref, p_obstacles, p_target)`` -- the obstacle
  data are parameters, so moving an obstacle is ``solver.set(k, "p", ...)``;
* ``con_h_expr = kit.rows(s, v, gate, ...)`` with ``lh = kit.lbg``,
  ``uh = ACADOS_INFTY``: the Theorem-1 rows of every stage, their
  certificate rows (cannot be dropped) and the gated target rows of the
  next belief (a run that ends inside the horizon);
* ``con_h_expr_e``: the terminal bundle of the belief at the horizon's end,
  switched on by ``gate[1]`` of the terminal node's parameters (a run that
  ends at the horizon's end), ``lh_e = terminal.lbg``; both sets of rows are
  unit-consistent (scaled: margins unit-free, target rows in sigma^2);
* ``cost_expr_ext_cost = kit.cost(s, v, gate, ref)``, zero terminal cost.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from .helpers import ACADOS_INFTY
from .kit import BeliefMPC

__all__ = ["acados_formulation", "acados_ocp", "stage_parameters"]


def stage_parameters(kit: BeliefMPC, gate: np.ndarray, ref: np.ndarray, p: np.ndarray | None = None,
                     p_t: np.ndarray | None = None) -> np.ndarray:
    """The acados parameter vector of one node: (gate, ref, p, p_t)."""
    p = kit.stage.params() if p is None else p
    p_t = kit.terminal.params() if p_t is None else p_t
    return np.concatenate([np.ravel(gate), np.ravel(ref), np.ravel(p), np.ravel(p_t)]).astype(float)


def acados_formulation(kit: BeliefMPC) -> dict[str, Any]:
    """The symbols, expressions and bounds an ``AcadosOcp`` needs (module doc),
    as a plain dict: x, u, p, disc_dyn_expr, con_h_expr, lh, uh, con_h_expr_e,
    lh_e, uh_e, cost_expr_ext_cost, cost_expr_ext_cost_e, parameter_values."""
    s, v = ca.SX.sym("s", kit.nx), ca.SX.sym("v", kit.nu)
    n_ref, n_p, n_pt = kit.n_ref, kit.stage.function.size1_in("p"), kit.terminal.function.size1_in("p")
    p = ca.SX.sym("p", 2 + n_ref + n_p + n_pt)
    gate, ref = p[:2], p[2:2 + n_ref]
    p_obs, p_t = p[2 + n_ref:2 + n_ref + n_p], p[2 + n_ref + n_p:]
    x, P = kit.unpack_state(s)
    te = kit.terminal(x, P, p_t)
    fin = gate[0] * gate[1]
    h_e = fin * te + (1 - fin) * kit.terminal.nominal
    return {
        "x": s, "u": v, "p": p,
        "disc_dyn_expr": kit.step(s, v),
        "con_h_expr": kit.rows(s, v, gate, p_obs, p_t),
        "lh": np.asarray(kit.lbg, float), "uh": np.full(kit.lbg.size, ACADOS_INFTY),
        "con_h_expr_e": h_e,
        "lh_e": np.asarray(kit.terminal.lbg, float), "uh_e": np.full(kit.terminal.lbg.size, ACADOS_INFTY),
        "cost_expr_ext_cost": kit.cost(s, v, gate, ref),
        "cost_expr_ext_cost_e": ca.SX(0),
        "parameter_values": stage_parameters(kit, np.array([1.0, 0.0]), np.zeros(n_ref)),
    }


def acados_ocp(kit: BeliefMPC, horizon: int, name: str = "belief_mpc"):
    """An ``acados_template.AcadosOcp`` of ``kit`` over ``horizon`` stages:
    discrete dynamics, external cost, ``con_h_expr`` / ``con_h_expr_e`` with
    their bounds, initial state from the scenario, SQP with exact Hessian."""
    from acados_template import AcadosModel, AcadosOcp

    f = acados_formulation(kit)
    model = AcadosModel()
    model.name = name
    for key in ("x", "u", "p", "disc_dyn_expr", "con_h_expr", "con_h_expr_e", "cost_expr_ext_cost",
                "cost_expr_ext_cost_e"):
        setattr(model, key, f[key])
    ocp = AcadosOcp()
    ocp.model = model
    ocp.cost.cost_type = ocp.cost.cost_type_e = "EXTERNAL"
    c = ocp.constraints
    c.lh, c.uh, c.lh_e, c.uh_e = f["lh"], f["uh"], f["lh_e"], f["uh_e"]
    c.x0 = kit.state(kit.scenario.x0, kit.scenario.P0)
    ocp.parameter_values = f["parameter_values"]
    so = ocp.solver_options
    if hasattr(so, "N_horizon"):
        so.N_horizon = int(horizon)
    else:                                          # acados < 0.4
        ocp.dims.N = int(horizon)
    so.tf = float(horizon)
    so.integrator_type = "DISCRETE"
    so.nlp_solver_type = "SQP"
    so.hessian_approx = "EXACT"
    so.qp_solver = "PARTIAL_CONDENSING_HPIPM"
    return ocp
