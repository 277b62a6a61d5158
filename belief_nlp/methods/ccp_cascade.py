"""The CCP step's solver cascade: which conic solvers and settings answer a
step, in which order, and how their answers are collected
(docs/numerics.md, "CCP solver cascade"). Used by :mod:`.ccp`."""

from __future__ import annotations

import importlib.util
import warnings
from typing import Callable

import numpy as np

from ..errors import ValidationError, solver_panicked
from ..model.cvxpy_form import CompiledProblem, usable_solvers
from ..smoother.context import SmoothingProblem

__all__ = ["solver_cascade", "LazyCascade", "SOLVER_DEFAULTS", "HIGH_ACCURACY"]

# The step's solver cascade (docs/numerics.md, "CCP solver cascade"). A step
# takes the first answer a solver reports optimal; an inaccurate answer is
# kept while the cheaper entries are tried, and taken if none is optimal (the
# exact check and the monotone test still decide); an answer they refuse
# (solver inaccuracy: the exact step is monotone and feasible) sends the
# step on to the next entry (_StepAnswers). Entries: the chosen solver with the
# library's settings (and the user's solver_options), the same solver with
# its own defaults, Clarabel with its defaults, SCS at high accuracy, then any
# other installed solver able to take the step, with its defaults.
#
# Clarabel's library settings: chordal decomposition and presolve off (the PSD
# cones are 2x2 to 6x6, nothing to decompose; with both off Clarabel accepts
# data updates, so CVXPY re-uses one solver object across iterations,
# ``warm_start=True``), equilibration off (measured in benchmarks/bench_ccp.py).
SOLVER_DEFAULTS = {"CLARABEL": {"equilibrate_enable": False, "chordal_decomposition_enable": False,
                                "presolve_enable": False}}
HIGH_ACCURACY = {"SCS": {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iters": 100_000}}
REUSE = {"CLARABEL"}
TIME_LIMIT_OPTION = {"CLARABEL": "time_limit", "SCS": "time_limit_secs"}
#: CVXPY's option that reports Clarabel's InsufficientProgress with a point as OPTIMAL_INACCURATE
ACCEPT_UNKNOWN = "accept_unknown"


def solver_cascade(solver: str, options: dict | None = None, budget: bool = False) -> list[tuple[str, str, dict]]:
    """The CCP step's cascade for ``solver``: [(solver, label, settings), ...]
    (see the comment above; installed solvers only). ``budget``: the step of a
    risk allocation, whose exponential budget cones Clarabel answers only
    inaccurately without presolve and equilibration (24 of 24 steps on
    paper-multi at Delta = 0.05; docs/numerics.md): its defaults come first."""
    usable = usable_solvers()
    lib = {} if budget else SOLVER_DEFAULTS.get(solver, {})
    out = [(solver, "library" if lib else "defaults", {**lib, **(options or {})})]
    if solver in SOLVER_DEFAULTS and out[0][2]:
        out.append((solver, "defaults", {}))
    if budget and solver in SOLVER_DEFAULTS:        # the library settings second (a defaults failure is rare)
        out.append((solver, "library", {**SOLVER_DEFAULTS[solver], **(options or {})}))
    for name, label, opts in (("CLARABEL", "defaults", {}), ("CLARABEL", "proximal", {}),
                              ("SCS", "high accuracy", HIGH_ACCURACY["SCS"])):
        if name in usable and not any(n == name and lab == label for n, lab, _ in out):
            out.append((name, label, dict(opts)))
    for name in usable:
        if all(n != name for n, _, _ in out):
            out.append((name, "defaults", {}))
    return out


class LazyCascade:
    """A cascade whose ``head`` entries are known now and whose rest,
    ``rest()``, is listed when first read: the active-set step needs only its
    own entry, and listing the installed solvers imports CVXPY (~0.35 s of a
    process's first call)."""

    def __init__(self, head: list[tuple[str, str, dict]], rest: Callable[[], list[tuple[str, str, dict]]]):
        self.head = list(head)
        self._rest = rest
        self._all: list | None = None

    def full(self) -> list[tuple[str, str, dict]]:
        if self._all is None:
            self._all = self.head + self._rest()
        return self._all

    def __getitem__(self, i):
        if self._all is None and isinstance(i, int) and 0 <= i < len(self.head):
            return self.head[i]
        if self._all is None and isinstance(i, slice) and i.start in (None, 0) and i.step is None \
                and i.stop is not None and 0 <= i.stop <= len(self.head):
            return self.head[i]
        return self.full()[i]

    def __len__(self) -> int:
        return len(self.full())

    def __iter__(self):
        return iter(self.full())


def _check_solver(name: str) -> str | None:
    if name.upper() == "CLARABEL" and importlib.util.find_spec("clarabel") is not None:
        # the default: the active-set step calls Clarabel itself, so checking it
        # through CVXPY's solver list would import CVXPY (~0.35 s of a first call)
        # for a cascade that may never reach CVXPY's entries
        return None
    import cvxpy as cp

    ok = usable_solvers()
    if name.upper() not in ok:
        if name.upper() not in cp.installed_solvers():
            return (f"{name!r} is not installed; usable installed solvers for the CCP step: {ok} "
                    f"(bn.available_solvers('ccp'))")
        return f"{name!r} cannot solve the CCP step (it needs PSD and exponential cones); usable installed solvers: {ok}"
    return None


def _check_solver_options(solver: str, options: dict) -> None:
    if solver == "CLARABEL":
        import clarabel

        st = clarabel.DefaultSettings()
        for k in options:
            if not hasattr(st, k) and k != ACCEPT_UNKNOWN:
                raise ValidationError("solver_options", f"{k!r} is not a Clarabel setting")


def _solve(step: CompiledProblem, solver: str, options: dict, time_left: float | None = None,
           reuse: bool = False) -> tuple[str, np.ndarray | None, float, int]:
    """Solve the step with exactly these settings: (status, z or None, solver time, iterations).

    ``reuse``: update the solver object of the previous solve in place (CVXPY's
    ``warm_start``), which keeps that solve's settings where ``options`` is
    silent; otherwise a new solver object gets exactly ``options``."""
    import cvxpy as cp

    opts = dict(options)
    if solver == "CLARABEL":
        # Clarabel's InsufficientProgress with a point is an inaccurate answer, not a failure
        # (CVXPY's own switch): the exact check and the monotone test decide, as for any. As a
        # failure it sent a 3-D budget step (rel. gap 5e-5) on to SCS for 60 s (docs/numerics.md)
        opts.setdefault(ACCEPT_UNKNOWN, True)
    if time_left is not None and solver in TIME_LIMIT_OPTION:     # the run's budget bounds one solve too
        opts[TIME_LIMIT_OPTION[solver]] = max(float(time_left), 1e-3)
    try:
        with warnings.catch_warnings():       # "may be inaccurate": the status says so, and the exact check decides
            warnings.simplefilter("ignore", UserWarning)
            step.problem.solve(solver=solver, warm_start=reuse and solver in REUSE, **opts)
    except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
        return f"error: {str(exc).splitlines()[0][:120]}", None, 0.0, 0
    except BaseException as exc:           # a Rust solver's panic is a failed solve, not a crash
        if not solver_panicked(exc):
            raise
        return f"error: solver panicked ({str(exc)[:100]})", None, 0.0, 0
    st = step.problem.solver_stats
    status = str(step.problem.status)
    ok = status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) and step.z.value is not None
    return _checked(status, np.asarray(step.z.value, float) if ok else None, float(st.solve_time or 0.0),
                    int(st.num_iters or 0), step)


class _StepAnswers:
    """The answers of one CCP step along the cascade, most trusted first.

    Solves lazily: an answer reported optimal is returned at once; one
    reported inaccurate waits until the interior-point entries of the cascade
    (Clarabel's, ~0.1-0.5 s each) are spent, and is returned before the
    first-order and other solvers are tried (SCS at high accuracy takes 10-80 s
    on a K = 20 step). Each solve is recorded in ``attempts``."""

    CHEAP = {"CLARABEL"}

    def __init__(self, step: CompiledProblem, cascade: list, problem: SmoothingProblem, fail: bool = False,
                 special: dict[str, Callable] | None = None, prepare: Callable[[], None] | None = None):
        self.step, self.cascade, self.problem, self.fail = step, cascade, problem, fail
        # entries solved another way: label -> fn(settings, time_left) -> (status, z, time, iterations) or None
        self.special = special or {}
        self.prepare = prepare          # sets the CVXPY step's parameters, before its first solve
        self.pos = 0
        self.inaccurate: list = []
        self.attempts: list[dict] = []
        self.solve_time, self.iterations = 0.0, 0

    def next(self) -> tuple[str, str, np.ndarray] | None:
        """(solver label, status, z) of the next answer, or None when the cascade is spent."""
        while True:
            entry = self._entry(self.pos) if not self.problem.out_of_time() else None
            if entry is not None and (entry[0] in self.CHEAP or not self.inaccurate):
                solver, label, opts = entry
                self.pos += 1
                if self.fail:                                   # injected fault (tests)
                    status, zv, t, n = "injected failure", None, 0.0, 0
                elif label in self.special:
                    out = self.special[label](opts, self.problem.time_left())
                    if out is None:                             # not available for this run
                        continue
                    status, zv, t, n = out
                else:
                    if self.prepare is not None:
                        self.prepare()
                        self.prepare = None
                    first = next(i for i, e in enumerate(self.cascade) if e[1] not in self.special)
                    status, zv, t, n = _solve(self.step, solver, opts, self.problem.time_left(),
                                              reuse=self.pos - 1 == first)  # the first CVXPY entry's solver lives on
                self.solve_time, self.iterations = self.solve_time + t, self.iterations + n
                self.attempts.append({"solver": solver, "settings": label, "status": status, "solve_time": t,
                                      "iterations": n})
                if zv is None:
                    continue
                if status == "optimal":          # (cvxpy.OPTIMAL; the active-set step says it too)
                    return f"{solver} ({label})", status, zv
                self.inaccurate.append((f"{solver} ({label})", status, zv))
            elif self.inaccurate:
                return self.inaccurate.pop(0)
            else:
                return None


    def _entry(self, i: int) -> tuple[str, str, dict] | None:
        """Entry i of the cascade, None past its end (a :class:`LazyCascade`
        lists its rest only when an entry there is read)."""
        try:
            return self.cascade[i]
        except IndexError:
            return None


def _checked(status: str, zv: np.ndarray | None, t: float, n: int, step: CompiledProblem):
    """A solver answer that is not a finite vector of the right length, or whose
    entries are absurd (|z| > 1e12 in the model's O(1) units), is a failed
    subproblem, whatever status the solver reported."""
    if zv is not None:
        zv = np.asarray(zv, dtype=float)
        if zv.shape != (step.layout.blocks.n,) or not np.all(np.isfinite(zv)) or np.max(np.abs(zv)) > 1e12:
            return f"{status} (unusable answer)", None, t, n
    return status, zv, t, n
