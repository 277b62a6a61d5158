"""SQP baseline: Uno's filter-SQP (trust-region SQP with the exact Hessian,
BQPD for the indefinite QP subproblems) through CasADi's ``"uno"`` nlpsol
plug-in, on the same NLP, stages and answer rules as IPOPT
(:mod:`belief_nlp.methods.nlp_engine`). The polish uses Uno's funnel-SQP
preset. What was tried and failed (CasADi's line-search ``sqpmethod`` with
every QP solver and convexification, ``feasiblesqpmethod``, ``blocksqp``,
SciPy's SLSQP) and the measurements: docs/numerics.md, "SQP baseline".
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import casadi as ca

from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.registry import Method, register
from .nlp_engine import NLPBackend, nlp_options, run_nlp

__all__ = ["run", "DEFAULT_UNO_OPTIONS", "map_status", "UNO"]

#: Uno settings used unless ``solver_options`` overrides them: primal
#: tolerances tight enough for the exact safety check (Uno's defaults end
#: at violations ~1e-6, the NLP's own margin).
DEFAULT_UNO_OPTIONS: dict[str, Any] = {
    "preset": "filtersqp",
    "logger": "SILENT",
    "print_solution": False,
    "primal_tolerance": 1e-8,
    "tight_unscaled_primal_infeasibility_tolerance": 1e-8,
}
POLISH_UNO_OPTIONS: dict[str, Any] = {"preset": "funnelsqp"}
#: Uno's presets (the SQP ones and its IPOPT-like barrier preset)
PRESETS = ("filtersqp", "funnelsqp", "filterslp", "ipopt")

def map_status(raw: str) -> str:
    """Uno's return status (through CasADi; ours for budget stops) -> one of :data:`STATUSES`."""
    low = raw.lower()
    return ("converged" if raw.startswith("Converged with feasible") else "max_iter" if "iteration" in low
            else "time_limit" if "time" in low else "solver_failed")


class UnoBackend(NLPBackend):
    """Uno through CasADi: presets per stage, its statuses."""

    name = "Uno"
    plugin = "uno"

    defaults = DEFAULT_UNO_OPTIONS
    stage_options = {"polish": POLISH_UNO_OPTIONS}
    limit_key = "max_iterations"
    tol_key = "tolerance"

    def check_options(self, opts: dict) -> str | None:
        # CasADi passes Uno's options through unchecked (an unknown name is
        # ignored, a bad preset fails only at solve time): check what we can
        if opts.get("preset") not in PRESETS:
            return f"Uno's preset must be one of {PRESETS}, got {opts.get('preset')!r}"
        for key, value in opts.items():
            if not isinstance(value, (str, bool, int, float)):
                return f"Uno option {key!r} must be a string, number or bool, got {type(value).__name__}"
        return None

    def map_status(self, raw: str) -> str:
        return map_status(raw)


UNO = UnoBackend()


def run(problem: SmoothingProblem, **options: Any) -> Outcome:
    """Uno's filter-SQP from the problem's start; ``options`` as in :data:`METHOD`
    (the driver passes every one, defaults filled in)."""
    return run_nlp(problem, UNO, **options)


def _check_solver(name: str) -> str | None:
    if name.upper() != "UNO":
        return f"method 'sqp' runs Uno only, got {name!r}"
    if not ca.has_nlpsol("uno"):
        return "this CasADi build has no 'uno' nlpsol plug-in (CasADi >= 3.7 wheels ship it)"
    return None


_OPTIONS = nlp_options("Uno")
_OPTIONS["polish"] = replace(_OPTIONS["polish"], default=200)      # funnel-SQP's polish: 7-101 iterations

METHOD = register(Method(
    name="sqp", run=run, max_iter=3000, default_solver="Uno", check_solver=_check_solver,
    description="SQP baseline: Uno's filter-SQP (exact Hessian, trust region) on the exact NLP through CasADi",
    iteration="one SQP iteration, log-Cholesky stage or polish",
    options=_OPTIONS,
))
