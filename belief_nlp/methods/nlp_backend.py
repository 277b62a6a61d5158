"""What one CasADi ``nlpsol`` plug-in needs from the NLP engine
(:mod:`belief_nlp.methods.nlp_engine`): its options per stage, its statuses,
its log. A solver file (``ipopt.py``, ``sqp.py``, ``fatrop.py``) subclasses
:class:`NLPBackend` and registers a method around it."""

from __future__ import annotations

import contextlib
from typing import Any

import casadi as ca

from ..model.nlp_form import NLPProblem

__all__ = ["NLPBackend", "solver_stats"]


def solver_stats(solver: Any) -> dict:
    """``solver.stats()``, or {} from a plug-in that has none after a failure."""
    try:
        return solver.stats()
    except RuntimeError:
        return {}


class NLPBackend:
    """How one CasADi ``nlpsol`` plug-in is driven. A solver file subclasses
    it and sets ``name`` (for results and messages) and ``plugin``."""

    name = "NLP"
    plugin = ""

    #: the plug-in's options unless the user's override them; per stage
    #: ("logchol", "cholesky", "polish") changes on top of them. A "rescue" entry:
    #: a first-stage restart from the start with those changes after an attempt
    #: found nothing safe below it (Uno: funnel-SQP; fatrop: mu_init 1e-3;
    #: docs/numerics.md, "SQP baseline", "fatrop")
    defaults: dict = {}
    stage_options: dict = {}
    #: names of the plug-in's own iteration limit and tolerance options
    limit_key = "max_iter"
    tol_key = "tol"
    #: ``ca.nlpsol`` options that take derivative functions, and the names of
    #: the solver's own functions for them: a second solver on the same NLP
    #: graph (the polish stage) is given the first one's instead of deriving
    #: them again (empty: the plug-in derives its own every time)
    shared_functions: dict = {}
    #: whether the polish starts from the first stage's multipliers (lam_x0,
    #: lam_g0 of the same NLP graph); the plug-in's "polish" stage options
    #: then say how it uses them (IPOPT: warm_start_init_point)
    warm_duals = False
    #: options of a first stage resumed from an earlier answer (the engine's
    #: ``resume``): from its variables and multipliers (backends with
    #: ``warm_duals``), or from the re-anchored answer on its graph (the others)
    resume_options: dict = {}
    #: whether the plug-in calls CasADi's ``iteration_callback`` every
    #: iteration. One that does not (fatrop) gets its stage budget as its own
    #: limit, no restarts and one history record per solve; the time limit
    #: inside a solve is then its :meth:`solve`'s to keep (fatrop: a watchdog)
    calls_back = True
    #: whether a restart may run inside the Kalman box (NLPProblem.kalman_box) and
    #: an iterate ten times outside it ends an attempt (measured for IPOPT only:
    #: docs/numerics.md, "The Kalman box")
    kalman_box = False

    def options(self, solver_options: dict, tol: float, stage: str) -> dict:
        """The plug-in's options for ``stage``, the user's ``solver_options``
        (with or without the "<plugin>." prefix) applied last. The plug-in's
        own limit is set out of reach: the recorder enforces the run's budget."""
        opts = {**self.defaults, **self.stage_options.get(stage, {}), self.limit_key: 10**7, self.tol_key: float(tol)}
        prefix = self.plugin + "."
        for key, value in solver_options.items():
            opts[key[len(prefix):] if key.startswith(prefix) else key] = value
        return opts

    def check_options(self, opts: dict) -> str | None:
        """What is wrong with the plug-in's options (None: fine). Plug-ins that
        validate their options when built (IPOPT) need nothing here."""
        return None

    def nlpsol_options(self, opts: dict, log_path: str | None) -> dict:
        """The ``ca.nlpsol`` options dict around the plug-in's options."""
        return {self.plugin: opts}

    def nlpsol(self, name: str, nlp: dict, options: dict) -> Any:
        """The solver instance: CasADi's ``nlpsol`` plug-in by default; a
        backend outside CasADi returns an object called the same way (keyword
        arguments x0, p, lbx, ubx, lbg, ubg -> dict with "x", "f", "g"; a
        ``stats()`` method) that drives ``options["iteration_callback"]``."""
        return ca.nlpsol(name, self.plugin, nlp, options)

    def pads(self, opts: dict) -> int:
        """Free variables nothing reads that :meth:`nlpsol` appends to the
        NLP's for plug-in options ``opts`` (IPOPT's cold solves: one,
        :mod:`.nlp_padded`): the solver's x, and its iteration callback's,
        are that much longer (none by default)."""
        return 0

    def attempt_stats(self, stats: dict) -> dict:
        """Raw solver statistics kept in each attempt's record (none by default)."""
        return {}

    def form(self, nlp: NLPProblem) -> Any:
        """The NLP form this solver is given (default: ``nlp`` itself; a
        structure-exploiting solver returns its stage-ordered form, which has
        the same attributes)."""
        return nlp

    def structure_options(self, nlp: Any) -> dict:
        """``ca.nlpsol`` options that describe ``nlp``'s structure (none by default)."""
        return {}

    def solving(self) -> contextlib.AbstractContextManager:
        """Context of every solve (fatrop: its unconditional stdout line silenced)."""
        return contextlib.nullcontext()

    def solve(self, solver: Any, args: dict, deadline: float | None) -> tuple[Any, dict, str]:
        """One call of ``solver`` with ``args``: (its solution, its stats,
        "" or why the call was ended from outside: "time_limit" once
        ``deadline`` passed, "stalled"). Raises RuntimeError as the solver
        does. fatrop runs it under a watchdog (:mod:`.nlp_guarded`)."""
        with self.solving():
            sol = solver(**args)
        return sol, solver_stats(solver), ""

    def return_status(self, stats: dict) -> str:
        """The solver's own return status from ``solver.stats()``."""
        return str(stats.get("return_status", "unknown"))

    def map_status(self, raw: str) -> str:
        """The solver's return status -> one of :data:`STATUSES`."""
        raise NotImplementedError

    def restoration(self, stats: dict, log_path: str | None, offset: int) -> int | None:
        """Restoration (or feasibility-phase) iterations of the last solve;
        None when the solver does not report them."""
        return None

    def refused(self, raw: str, opts: dict, log_path: str | None, offset: int) -> str | None:
        """Why the plug-in refused its options when it solved (None: it did
        not). For options a plug-in checks only then (IPOPT loads a linear
        solver's library at its first solve); the engine raises it as a
        :class:`~belief_nlp.errors.ValidationError` of ``solver_options``."""
        return None

    def log_file(self) -> str | None:
        """A log file the solver writes (None: no log)."""
        return None
