"""Exception types of belief_nlp.

Every error the library raises on purpose derives from :class:`BeliefNLPError`,
so a study can catch the whole family in one ``except`` clause, record the case
and go on.
"""

from __future__ import annotations

__all__ = [
    "BeliefNLPError",
    "ValidationError",
    "ScenarioFileError",
    "InfeasibleStartError",
    "SolverError",
]


class BeliefNLPError(Exception):
    """Base class of every exception raised by belief_nlp."""


class ValidationError(BeliefNLPError, ValueError):
    """Bad input: the message names the field and what is wrong with it.

    Attributes
    ----------
    field:
        Dotted name of the offending field (``"obstacles[2].vertices"``,
        ``"start.P"``), or ``""`` when the fault is not tied to one field.
    """

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}" if field else problem)


class ScenarioFileError(ValidationError):
    """A file cannot be read or does not follow its schema.

    Raised for scenario files (schema faults too), and for path and result
    files that are missing, unreadable, malformed, not a zip archive (NPZ),
    too large or nested too deeply (limits in ``belief_nlp._limits``).
    """


class InfeasibleStartError(BeliefNLPError, ValueError):
    """No feasible initial point of the smoothing problem could be built.

    Attributes
    ----------
    transition:
        1-based index k of the transition t_{k-1} -> t_k at fault (or None).
    obstacle:
        Name of the obstacle / wall / target face at fault (or None).
    """

    def __init__(self, message: str, transition: int | None = None, obstacle: str | None = None):
        self.transition = transition
        self.obstacle = obstacle
        super().__init__(message)


class SolverError(BeliefNLPError, RuntimeError):
    """A numerical solver is missing or failed in a way that leaves no usable result."""


def solver_panicked(exc: BaseException) -> bool:
    """Whether ``exc`` is a panic of a solver written in Rust (Clarabel):
    pyo3 raises ``pyo3_runtime.PanicException``, a BaseException, so an
    ``except Exception`` does not see it. The smoothers treat it as a failed
    solve (seen: Clarabel's PSD step length on an eigenvalue failure)."""
    return type(exc).__name__ == "PanicException"
