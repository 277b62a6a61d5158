"""fatrop on the stage-ordered NLP through CasADi's ``"fatrop"`` nlpsol
plug-in: the :class:`~belief_nlp.methods.nlp_engine.NLPBackend` of fatrop.

fatrop is an interior-point method like IPOPT whose KKT systems are solved
by a Riccati recursion over the stages of an optimal control problem, so it
needs the NLP in stage order with gap-closing rows
(:mod:`belief_nlp.model.ocp_form`); the structure (N, nx, nu, ng) is given
to the plug-in explicitly ("manual" structure detection). The stages,
restarts and answer rules are the engine's
(:mod:`belief_nlp.methods.nlp_engine`), the same as IPOPT's. Measured
against IPOPT on the same NLP and starts: docs/numerics.md, "fatrop".
"""

from __future__ import annotations

import contextlib
import os
import sys
from functools import lru_cache
from typing import Any, Iterator

import casadi as ca

from ..model.nlp_form import NLPProblem
from ..model.ocp_form import OCPProblem, build_ocp
from ..smoother.context import Outcome, SmoothingProblem
from ..smoother.registry import Method, register
from .nlp_backend import solver_stats
from .nlp_engine import NLPBackend, nlp_options, run_nlp
from .nlp_guarded import can_fork, guarded_call

__all__ = ["run", "DEFAULT_FATROP_OPTIONS", "map_status", "FATROP", "available"]

#: fatrop settings used unless ``solver_options`` overrides them: IPOPT's
#: bound push (the default 1e-2 took 5x the iterations from our warm starts)
#: and a primal tolerance tight enough for the exact safety check.
DEFAULT_FATROP_OPTIONS: dict[str, Any] = {
    "print_level": 0,
    "bound_push": 1e-4,
    "bound_frac": 1e-4,
    "constr_viol_tol": 1e-8,
}

#: a first stage that failed restarts from its start with this first barrier
#: parameter: on the issue-21 protocol the 12 of 80 runs that failed converged
#: with it, the one that hung included (session 19; as every run's setting it took
#: more iterations at K = 20 and failed 4 others)
RESCUE_FATROP_OPTIONS: dict[str, Any] = {"mu_init": 1e-3}

#: a re-plan's first stage from the re-anchored last answer, on its graph
#: (fatrop takes no multipliers to resume from): a small first barrier keeps
#: it near that answer instead of pushing it into the interior. Loops on
#: paper-multi (session 29, 3-4 seeds x 5 re-plans): median 0.35 -> 0.18 s at
#: K = 20 and 1.9-3.5 -> 0.32-0.35 s at K = 40 (1e-4 failed 4 of 15 at K = 40;
#: docs/numerics.md, "fatrop")
RESUME_FATROP_OPTIONS: dict[str, Any] = {"mu_init": 1e-5}

#: fatrop's print level that writes a line per iteration: the watchdog's
#: heartbeat (:mod:`.nlp_guarded`); the user's ``print_level`` > 0 shows them
_HEARTBEAT_LEVEL = 5

#: CasADi's unified return statuses (fatrop's own flag is an integer)
_LIMITED = {"SOLVER_RET_LIMITED"}


def available() -> bool:
    """Whether this CasADi build ships the fatrop plug-in."""
    try:
        return bool(ca.has_nlpsol("fatrop"))
    except RuntimeError:
        return False


def map_status(raw: str) -> str:
    """Our raw fatrop status ("Success" / "<CasADi unified status> (flag n)",
    or the engine's budget stops) -> one of :data:`STATUSES`."""
    if raw == "Success":
        return "converged"
    low = raw.lower()
    if "iteration" in low or any(s in raw for s in _LIMITED):
        return "max_iter"
    if "walltime" in low or "time" in low.split("_"):
        return "time_limit"
    return "solver_failed"


@lru_cache(maxsize=64)
def _probe(items: tuple) -> str | None:
    """Solve a two-stage toy OCP with these fatrop options: the plug-in
    checks option names and types only when it solves (an unknown name is a
    RuntimeError then), so the check is a real solve, cached per option set."""
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 2)
    z = ca.vertcat(x[0], u[0], x[1], u[1])
    g = ca.vertcat(x[1] - x[0] - u[0], x[1] + u[1] - 1)
    f = ca.sumsqr(z)
    try:
        with _quiet():
            s = ca.nlpsol("belief_nlp_fatrop_probe", "fatrop", {"x": z, "f": f, "g": g},
                          {"structure_detection": "manual", "N": 1, "nx": [1, 1], "nu": [1, 1], "ng": [0, 1],
                           "print_time": False, "error_on_fail": False,
                           "fatrop": {**dict(items), "print_level": 0, "max_iter": 5}})
            s(x0=0, lbg=[0, 0], ubg=[0, 0])
    except RuntimeError as exc:
        lines = [ln for ln in str(exc).splitlines() if ln.strip()]
        return f"fatrop refused them: {lines[-1].strip()[:200] if lines else exc}"
    return None


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """The plug-in writes a line to the C-level stdout on every solve
    ("Creating OcpSolver Driver ..."), whatever its print level: silence
    file descriptor 1 while it runs."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, ValueError, OSError):     # no real stdout (notebooks, captured output)
        fd = 1
    try:
        sys.stdout.flush()
        saved = os.dup(fd)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


class FatropBackend(NLPBackend):
    """fatrop: the stage-ordered NLP, its structure, statuses and option check."""

    name = "fatrop"
    stage_options = {"rescue": RESCUE_FATROP_OPTIONS}
    plugin = "fatrop"
    defaults = DEFAULT_FATROP_OPTIONS
    resume_options = RESUME_FATROP_OPTIONS
    calls_back = False          # the plug-in never calls CasADi's iteration_callback (measured)

    def form(self, nlp: NLPProblem) -> OCPProblem:
        return build_ocp(nlp)

    def structure_options(self, nlp: OCPProblem) -> dict:
        return {"structure_detection": "manual", "N": nlp.N, "nx": nlp.nx, "nu": nlp.nu, "ng": nlp.ng}

    def check_options(self, opts: dict) -> str | None:
        for key, value in opts.items():
            if not isinstance(value, (str, bool, int, float)):
                return f"fatrop option {key!r} must be a string, number or bool, got {type(value).__name__}"
        return _probe(tuple(sorted((k, v) for k, v in opts.items() if k not in (self.limit_key, "print_level"))))

    def nlpsol(self, name: str, nlp: dict, options: dict) -> Any:
        own = dict(options[self.plugin])
        shown = own.get("print_level", 0) not in (0, False)
        beats = can_fork()
        if beats:           # its iteration lines are the watchdog's heartbeat
            own["print_level"] = _HEARTBEAT_LEVEL
        solver = ca.nlpsol(name, self.plugin, nlp, {**options, self.plugin: own})
        solver.belief_nlp_shown = shown     # the user's print_level > 0: the lines are shown
        solver.belief_nlp_beats = beats
        return solver

    def solve(self, solver: Any, args: dict, deadline: float | None) -> tuple[Any, dict, str]:
        """In a forked child under the watchdog of :mod:`.nlp_guarded` (a
        fatrop solve cannot be stopped otherwise, and one was seen to hang
        inside an iteration); in the process where ``os.fork`` is missing."""
        if not (can_fork() and getattr(solver, "belief_nlp_beats", False)):
            return super().solve(solver, args, deadline)
        sol, st, ended = guarded_call(solver, args, solver_stats, deadline,
                                      echo=getattr(solver, "belief_nlp_shown", False))
        return sol, st, ended or ""

    def return_status(self, stats: dict) -> str:
        if stats.get("success"):
            return "Success"
        return f"{stats.get('unified_return_status', 'unknown')} (flag {stats.get('return_status', '?')})"

    def map_status(self, raw: str) -> str:
        return map_status(raw)

    def solving(self) -> contextlib.AbstractContextManager:
        return _quiet()


FATROP = FatropBackend()


def run(problem: SmoothingProblem, **options: Any) -> Outcome:
    """fatrop from the problem's start; ``options`` as in :data:`METHOD`
    (the driver passes every one, defaults filled in)."""
    return run_nlp(problem, FATROP, **options)


def _check_solver(name: str) -> str | None:
    if name.lower() != "fatrop":
        return f"method 'fatrop' runs fatrop only, got {name!r}"
    if not available():
        return "this CasADi build has no 'fatrop' nlpsol plug-in (CasADi >= 3.6 wheels ship it)"
    return None


#: fatrop's own iteration limit bounds a solve that progresses; one that hangs
#: inside an iteration (seen at K = 40) is ended by the watchdog of
#: :mod:`.nlp_guarded`, as is one past the time limit (docs/numerics.md, "fatrop").
#: 3000 as IPOPT's and SQP's: the 300 kept from before the watchdog stopped 4 of
#: 40 K = 20 and 15 of 40 K = 40 runs that converge in 364-1688 (session 19)
METHOD = register(Method(
    name="fatrop", run=run, max_iter=3000, default_solver="fatrop", check_solver=_check_solver,
    description="fatrop (Riccati-structured interior point) on the stage-ordered exact NLP through CasADi; "
                "floored log-Cholesky stage, then an exact-Cholesky polish",
    iteration="one fatrop iteration, log-Cholesky stage or polish",
    options=nlp_options("fatrop"),
)) if available() else None
