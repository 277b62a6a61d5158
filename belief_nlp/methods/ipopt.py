"""IPOPT on the exact NLP through CasADi's ``nlpsol``, from the same warm start
as CCP: the :class:`~belief_nlp.methods.nlp_engine.NLPBackend` of IPOPT.
The stages, restarts and answer rules are the engine's
(:mod:`belief_nlp.methods.nlp_engine`); the settings and the measurements
behind them are in docs/numerics.md, "IPOPT" and "IPOPT iterations".
"""

from __future__ import annotations

import os
import re
import tempfile
from typing import Any

from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.registry import Method, Option, real, register
from .nlp_engine import NLPBackend, clear_cache, nlp_options, run_nlp
from .nlp_padded import PaddedSolver, pads
from .solver_logs import log_dir

__all__ = ["run", "DEFAULT_IPOPT_OPTIONS", "map_status", "clear_cache", "IPOPT"]

#: IPOPT settings used unless ``solver_options`` overrides them (docs/numerics.md).
DEFAULT_IPOPT_OPTIONS: dict[str, Any] = {
    "mu_strategy": "adaptive",
    "mu_oracle": "loqo",
    "bound_push": 1e-4,
    "bound_frac": 1e-4,
    "constr_viol_tol": 1e-8,
    "print_level": 0,
    "sb": "yes",
}

#: changes for the floored log-Cholesky stage and for the polish after it.
#: The stage's barrier floor: 3e-6 keeps its iterates off their bounds, so
#: fewer steps are cut short (-18 % wall at K = 20, -19 % at K = 40, about
#: -50 % at K = 80 against 1e-7; docs/numerics.md, "The first stage's barrier
#: floor"); the polish takes the answer the rest of the way
LOGCHOL_IPOPT_OPTIONS: dict[str, Any] = {"mu_min": 3e-6}
#: The polish's barrier stays at mu_init: IPOPT's monotone update never lowers mu
#: below min(tol, compl_inf_tol) / (barrier_tol_factor + 1), and with tol = 1e-4 and
#: the default compl_inf_tol (1e-4) that floor, 9.1e-6, is above 1e-8, so the first
#: "decrease" after a barrier problem solved short of constr_viol_tol raised mu a
#: thousandfold and the polish walked off its answer to the cap (5 of 40 at K = 40;
#: compl_inf_tol 1e-7 puts the floor at 9.1e-9; docs/numerics.md, "The polish's barrier")
POLISH_IPOPT_OPTIONS: dict[str, Any] = {"mu_strategy": "monotone", "mu_init": 1e-8, "compl_inf_tol": 1e-7,
                                        # the first stage's multipliers as the start's (NLPBackend.warm_duals),
                                        # the start pushed no further into the interior than mu_init
                                        "warm_start_init_point": "yes", "warm_start_bound_push": 1e-9,
                                        "warm_start_bound_frac": 1e-9, "warm_start_slack_bound_push": 1e-9,
                                        "warm_start_slack_bound_frac": 1e-9, "warm_start_mult_bound_push": 1e-9}

#: a first stage resumed from an earlier answer's variables and multipliers
#: (bn.replan): started from them, pushed no further into the interior than
#: 1e-9 (docs/numerics.md, "The start belief as a parameter, and
#: re-planning"). mu_init matters only to a monotone barrier (a user's
#: mu_strategy): under the default adaptive one 1e-4, 1e-6 and 1e-8 gave the
#: same iterates (session 14, "A receding horizon on the longer graph").
#: Its barrier floor stays 1e-7: the resumed start is near an answer, and a
#: floor above mu_init would undo that
RESUME_IPOPT_OPTIONS: dict[str, Any] = {"warm_start_init_point": "yes", "mu_init": 1e-6, "mu_min": 1e-7,
                                        "warm_start_bound_push": 1e-9, "warm_start_bound_frac": 1e-9,
                                        "warm_start_slack_bound_push": 1e-9, "warm_start_slack_bound_frac": 1e-9,
                                        "warm_start_mult_bound_push": 1e-9}

#: the means' scale of the "logchol" stage (nlp_scaled.py; docs/numerics.md,
#: "K = 80: continuation and sensing pattern (session 10)")
SCALE_MEANS = 1.0

_CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
_MAX_ITER = {"Maximum_Iterations_Exceeded"}
_TIME = {"Maximum_CpuTime_Exceeded", "Maximum_WallTime_Exceeded"}
_RESTO = re.compile(rb"^\s*\d+r\s", re.M)
_REASON = re.compile(r"(?:Exception message|EXIT):\s*(.+)")


def map_status(ipopt_status: str) -> str:
    """IPOPT's return status -> one of :data:`STATUSES` (before the exact check)."""
    if ipopt_status in _CONVERGED:
        return "converged"
    if ipopt_status in _MAX_ITER:
        return "max_iter"
    if ipopt_status in _TIME:
        return "time_limit"
    return "ipopt_failed"


class IpoptBackend(NLPBackend):
    """IPOPT: defaults per stage, its statuses, restoration iterations from its log."""

    name = "IPOPT"
    plugin = "ipopt"

    defaults = DEFAULT_IPOPT_OPTIONS
    stage_options = {"logchol": LOGCHOL_IPOPT_OPTIONS, "polish": POLISH_IPOPT_OPTIONS}
    shared_functions = {"grad_f": "nlp_grad_f", "jac_g": "nlp_jac_g", "hess_lag": "nlp_hess_l"}
    warm_duals = True
    kalman_box = True
    resume_options = RESUME_IPOPT_OPTIONS

    def nlpsol_options(self, opts: dict, log_path: str | None) -> dict:
        # IPOPT reports f, g and the multipliers of its answer itself; CasADi
        # recomputing them needs a gradient-of-the-Lagrangian function, whose
        # derivation was 40 ms of each stage's construction at K = 20 (same
        # answers, iterations and costs bit for bit on 10 cases; numerics.md)
        return {"ipopt": {**opts, "output_file": log_path, "file_print_level": 5},
                "no_nlp_grad": True, "calc_lam_x": False, "calc_lam_p": False, "calc_f": False, "calc_g": False}

    def pads(self, opts: dict) -> int:
        return pads(opts)

    def nlpsol(self, name: str, nlp: dict, options: dict) -> Any:
        # a cold solve gets one free variable more: IPOPT then skips a factorisation
        # that fails its inertia test in 92 % of the iterations (nlp_padded)
        if pads(options[self.plugin]):
            return PaddedSolver(name, self.plugin, nlp, options)
        return super().nlpsol(name, nlp, options)

    def map_status(self, raw: str) -> str:
        return map_status(raw)

    def log_file(self) -> str:
        """A fresh log file in a per-process folder (:mod:`.solver_logs`). CasADi's
        IPOPT statistics carry no restoration flag; the log's iteration table
        marks restoration iterations with "r", so each solve reads its part."""
        fd, path = tempfile.mkstemp(suffix=".log", dir=log_dir("ipopt"))
        os.close(fd)
        return path

    def refused(self, raw: str, opts: dict, log_path: str | None, offset: int) -> str | None:
        # an unavailable linear solver (ma27, ma57, pardiso, ...) passes nlpsol's
        # check and fails at the solve with Invalid_Option; the log says why
        if raw != "Invalid_Option":
            return None
        found = _REASON.search(_log_since(log_path, offset).decode(errors="replace"))
        why = found.group(1).strip() if found else "Invalid_Option at its first iteration"
        ls = opts.get("linear_solver")
        hint = f" (linear_solver {ls!r}: its library is not installed here; IPOPT's default is 'mumps')" \
            if ls not in (None, "mumps") and "shared object" in why else ""
        return f"IPOPT refused them when solving: {why}{hint}"

    def restoration(self, stats: dict, log_path: str | None, offset: int) -> int:
        return len(_RESTO.findall(_log_since(log_path, offset)))


def _log_since(log_path: str | None, offset: int) -> bytes:
    """What IPOPT wrote to its log from byte ``offset`` on (the last solve's part); empty without a log."""
    try:
        with open(log_path, "rb") as fh:
            fh.seek(offset)
            return fh.read()
    except (OSError, TypeError):
        return b""


IPOPT = IpoptBackend()


def run(problem: SmoothingProblem, **options: Any) -> Outcome:
    """IPOPT from the problem's start; ``options`` as in :data:`METHOD`
    (the driver passes every one, defaults filled in)."""
    return run_nlp(problem, IPOPT, **options)


METHOD = register(Method(
    name="ipopt", run=run, max_iter=3000, default_solver="IPOPT",
    check_solver=lambda s: None if s.upper() == "IPOPT" else f"method 'ipopt' runs IPOPT only, got {s!r}",
    description="IPOPT on the exact NLP (S = L L^T, Q = M M^T, Kalman equality), exact Hessian; "
                "floored log-Cholesky stage, then an exact-Cholesky polish",
    iteration="one IPOPT iteration, log-Cholesky stage or polish",
    options={**nlp_options("IPOPT"),
             "scale_means": Option(SCALE_MEANS, "the means' scale in the 'logchol' stage: IPOPT solves for y = x / "
                                                "scale_means (1: unscaled); a larger scale keeps IPOPT's inertia "
                                                "correction from damping the path's smooth modes",
                                   lambda v: None if 0 < (real(v) or 0) < float("inf")
                                   else "must be a finite number > 0")},
))
