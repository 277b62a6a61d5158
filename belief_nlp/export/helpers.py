"""Constraint rows of one transition in do-mpc's and acados' conventions
(the per-call helpers of the first export; the bundles of :mod:`.bundle`
are the stacked, parametric form). Every helper ships the lam >= 0 rows with
the margins, so a belief inside an obstacle is never "clear"."""

from __future__ import annotations

from typing import Any, Sequence

import casadi as ca
import numpy as np

from ..errors import ValidationError
from ..scenario import Scenario
from .functions import _slug, export_functions

__all__ = ["clearance_margins", "dompc_constraints", "acados_constraints", "ACADOS_INFTY"]

#: Upper bound used for one-sided acados constraints (acados treats bounds of
#: this size as infinite for the HPIPM QP solver; its constant ACADOS_INFTY).
ACADOS_INFTY = 1e10


def clearance_margins(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None,
                      x_final=None, P_final=None) -> tuple[list[str], Any]:
    """All safety margins of one transition as one column expression (>= 0 safe).

    ``x_prev`` (d), ``P_prev`` (d, d), ``x_next`` (d) and ``lams`` (one (f_j,)
    vector per hazard of ``scenario.hazards``) may be SX, MX or numbers; ``W``
    defaults to the scenario's per-step noise. Rows: for each hazard the
    Theorem-1 start and end margins; with ``x_final``/``P_final``, the target
    containment margins (metres) at the end. Returns (row names, expression).
    """
    funcs = export_functions(scenario)
    if len(lams) != len(scenario.hazards):
        raise ValidationError("lams", f"give one certificate per hazard ({len(scenario.hazards)}), got {len(lams)}")
    W = scenario.W if W is None else W
    names, rows = [], []
    for h, lam in zip(scenario.hazards, lams):
        s = _slug(h.name)
        m0, m1 = funcs[f"transition_{s}"](x_prev, P_prev, x_next, W, lam)
        names += [f"{s}_start", f"{s}_end"] + [f"{s}_lam_{f}" for f in range(h.n_faces)]
        rows += [m0, m1, ca.vec(lam)]
    if x_final is not None:
        tm = funcs["target_containment"](x_final, P_final)
        names += [f"target_face_{n}" for n in range(scenario.target.n_faces)]
        rows.append(tm)
    return names, ca.vertcat(*rows)


def dompc_constraints(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None, x_final=None,
                      P_final=None, margin: float = 0.0) -> list[tuple[str, Any, float]]:
    """The safety constraints in do-mpc's convention.

    do-mpc's ``mpc.set_nl_cons(name, expr, ub)`` keeps ``expr <= ub``; a
    margin m >= margin becomes ``expr = -m``, ``ub = -margin``. Returns one
    (name, expr, ub) triple per row of :func:`clearance_margins`, e.g.::

        for name, expr, ub in dompc_constraints(sc, x, P, x_next, lams):
            mpc.set_nl_cons(name, expr, ub=ub)
    """
    names, h = clearance_margins(scenario, x_prev, P_prev, x_next, lams, W, x_final, P_final)
    return [(n, -h[i], -_row_margin(n, margin)) for i, n in enumerate(names)]


def acados_constraints(scenario: Scenario, x_prev, P_prev, x_next, lams: Sequence, W=None, x_final=None,
                       P_final=None, margin: float = 0.0) -> tuple[Any, np.ndarray, np.ndarray]:
    """The safety constraints in acados' convention ``lh <= h(x, u) <= uh``.

    Returns (h, lh, uh) with h = the margins of :func:`clearance_margins`,
    lh = margin, uh = :data:`ACADOS_INFTY` (one-sided); use as
    ``model.con_h_expr = h; ocp.constraints.lh = lh; ocp.constraints.uh = uh``
    (or the ``_e`` variants at the terminal stage).
    """
    names, h = clearance_margins(scenario, x_prev, P_prev, x_next, lams, W, x_final, P_final)
    return h, np.array([_row_margin(n, margin) for n in names]), np.full(len(names), ACADOS_INFTY)


def _row_margin(name: str, margin: float) -> float:
    """Lower bound of a row: ``margin`` for safety margins, 0 for certificate rows."""
    return 0.0 if "_lam_" in name else float(margin)
