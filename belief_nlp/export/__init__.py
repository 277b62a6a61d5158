"""CasADi exports of the belief model for MPC stacks.

Everything is built from the one symbolic model (:mod:`belief_nlp.model.terms`):

* :mod:`.bundle` -- the safety constraints of a scenario as two stacked,
  parametric functions with bounds, names and scales: :func:`stage_bundle`
  (Theorem-1 transitions against every hazard) and :func:`terminal_bundle`
  (target containment, squared form); SI or scaled, hard or soft;
* :mod:`.certificates` -- :func:`certificate_warm_start` from any reference path;
* :mod:`.kit` -- :class:`BeliefMPC`, the stage layout (state, input,
  dynamics, rows, cost) the adapters install;
* adapters: :mod:`.opti` (``casadi.Opti``), :mod:`.dompc` (do-mpc),
  :mod:`.rockit` (rockit), :mod:`.acados` (acados);
* :mod:`.closed_loop` -- receding-horizon runs with any of the tools;
* :mod:`.codegen` -- :func:`generate`: C code of a bundle and its derivatives;
* :mod:`.functions`, :mod:`.helpers`, :mod:`.demo` -- the per-hazard
  functions, constraint rows and the corridor demo of the first export.

Units: SI at the public boundary (metres, m^2, 1/m^2 for sensing, 1/m for
certificates) unless a bundle is ``scaled`` (its ``factors`` convert).
See docs/mpc.md.
"""

from __future__ import annotations

from .bundle import PAD_OFFSET, SafetyBundle, TerminalBundle, scale_factors, stage_bundle, terminal_bundle
from .certificates import certificate_warm_start
from .codegen import generate
from .closed_loop import TOOLS, closed_loop
from .demo import demo_scenario, mpc_demo
from .functions import (_slug, belief_predict, belief_update, ellipse_clearance, export_functions,  # noqa: F401
                        information_cost, load_functions, save_functions, target_containment,
                        transition_clearance)
from .helpers import ACADOS_INFTY, acados_constraints, clearance_margins, dompc_constraints
from .kit import BeliefMPC, reference_path

__all__ = [
    "belief_predict", "belief_update", "information_cost", "ellipse_clearance", "transition_clearance",
    "target_containment", "export_functions", "save_functions", "load_functions", "clearance_margins",
    "dompc_constraints", "acados_constraints", "ACADOS_INFTY", "demo_scenario", "mpc_demo",
    "SafetyBundle", "TerminalBundle", "stage_bundle", "terminal_bundle", "scale_factors", "PAD_OFFSET",
    "certificate_warm_start", "BeliefMPC", "reference_path", "generate", "closed_loop", "TOOLS",
]
