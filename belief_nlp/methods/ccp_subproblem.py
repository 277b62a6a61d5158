"""The first CCP step as a ``cvxpy.Problem`` users take out (``bn.ccp_subproblem``)
and the map of its answer back to a :class:`~belief_nlp.BeliefPath`."""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError
from ..inputs import as_path, as_scenario
from ..model import BeliefModel
from .ccp import compiled_step, initial_rho

__all__ = ["ccp_subproblem", "ccp_subproblem_path"]


def ccp_subproblem(scenario, path, K: int | None = None, alpha: float | None = None):
    """The convex subproblem of the first CCP step, as a ``cvxpy.Problem``.

    Built from ``path``'s warm start with its parameters set, ready to
    ``.solve()``, to print, or to hand to another solver.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario, or a built-in name / scenario file.
    path : BeliefPath, result or WarmStart
        A feasible path (or a plan or smoothing result holding one), or a
        warm start used as it is.
    K : int, optional
        Horizon of the warm start; None as in :func:`belief_nlp.warm_start`.
    alpha : float, optional
        Information weight; None uses the scenario's.

    Returns
    -------
    cvxpy.Problem
        A DPP problem of its own (every call returns a new one; solving it
        leaves other problems alone), every parameter set at the warm start.
        ``prob.solve()`` lets CVXPY pick the solver: with this package's
        dependencies (cvxpy 1.9) that is SCS, at its default accuracy (about
        1e-5 relative in the objective, 4-10 s at K = 20);
        ``prob.solve(solver="CLARABEL")`` is about ten times faster and
        tighter. Neither needs settings (tests/test_ccp_step.py). A solver's
        answer meets the constraints to its tolerance only: check a path with
        :func:`belief_nlp.verify` (the smoother checks every step exactly).
        Its variable ``z`` is the model's decision vector in scaled units
        (lengths in units of sigma = sqrt(max eig W): the means' steps, Q, S,
        certificates and auxiliaries; docs/architecture.md);
        :func:`ccp_subproblem_path` maps the solved problem back to a
        :class:`BeliefPath` in SI units.

    Raises
    ------
    InfeasibleStartError
        When no feasible warm start can be built from ``path``.
    ValidationError
        For bad arguments, naming the argument.
    """
    import pickle

    from ..smoother.warmstart import WarmStart, warm_start

    sc = as_scenario(scenario)
    p = as_path(path)
    warm = p if isinstance(p, WarmStart) else warm_start(sc, p, K=K)
    model = BeliefModel(sc, warm.K, alpha)
    start = model.tighten(model.from_path(warm.path, warm.lam))
    shared, _, _ = compiled_step(model)
    # its own variables and parameters, with the compiled form (the disk cache's round trip: a pickle
    # keeps the leaves' ids, which the compiled chain is keyed by; copy.deepcopy gives new ids)
    step = pickle.loads(pickle.dumps(shared))
    for var in step.problem.variables():       # no answer from an earlier solve of the shared problem
        var.value = None
    rho = initial_rho(model, start)
    step.set_point(start, rho, rho)
    step.problem._belief_nlp_step = (step, model, start)
    return step.problem


def ccp_subproblem_path(problem):
    """The :class:`BeliefPath` (SI units) of a solved :func:`ccp_subproblem`.

    Parameters
    ----------
    problem : cvxpy.Problem
        A problem returned by :func:`ccp_subproblem`, solved by any solver.

    Returns
    -------
    BeliefPath
        The step's means and sensing; priors by the Kalman recursion (Lemma 2).
        It meets the constraints to the solver's tolerance: check it with
        :func:`belief_nlp.verify`.

    Raises
    ------
    ValidationError
        ``problem`` is not from :func:`ccp_subproblem`, or is not solved.
    """
    ctx = getattr(problem, "_belief_nlp_step", None)
    if ctx is None:
        raise ValidationError("problem", "is not a problem made by ccp_subproblem")
    step, model, start = ctx
    if step.z.value is None:
        raise ValidationError("problem", f"has no solution (status {problem.status!r}): solve it first")
    return model.to_path(model.tighten(step.layout.extract(np.asarray(step.z.value, float), start)))
