"""Re-planning from a new start belief, warm started from a previous answer.

In a control loop the robot's belief moves between plans (a step executed,
a measurement fused, a disturbance), and the last answer is a far better
start than a new IG-RRT* plan: its means are smooth and its sensing is
where the cost wants it. :func:`replan` re-anchors that answer at the
scenario's start belief, keeps its sensing (``warm_start(...,
sensing="path")``, which adds sensing only where a transition needs it)
and smooths; IPOPT resumes from the last answer's variables and
multipliers (its exact polish alone when that gave the answer, else its
first stage: :mod:`belief_nlp.methods.nlp_resume`), and CCP from the last
answer's conic step. The start belief is
a parameter of every solver form, so on the same scenario and horizon
nothing is built again; after executed steps the last answer's graph is
solved with them frozen (:mod:`belief_nlp.model.nlp_prefix`), so a
receding-horizon loop builds nothing either (docs/performance.md,
"Re-planning from a new belief").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ValidationError
from ..methods import nlp_resume
from ..path import BeliefPath
from ..scenario import Scenario
from .driver import smooth
from .registry import DEFAULT_METHOD, Method, get_method
from .result import SmoothResult
from .warmstart import WarmStart

__all__ = ["replan", "reanchor"]


def reanchor(scenario: Scenario, previous: SmoothResult | BeliefPath | WarmStart, advance: int = 0) -> BeliefPath:
    """The path of ``previous`` moved to the scenario's start belief.

    Its means after step ``advance`` follow the scenario's x0, with their
    sensing; the covariances are rolled out again from the scenario's P0
    under its per-step noise W. ``advance`` is the number of steps executed
    since ``previous`` was planned (0: the same horizon, only the start
    belief moved; k: the first k steps are done, the horizon is K - k).

    Parameters
    ----------
    scenario : Scenario
        The problem with the robot's current belief as its start (x0, P0).
    previous : SmoothResult, WarmStart or BeliefPath
        The last plan.
    advance : int, optional
        Steps executed since ``previous`` (0 <= advance < its K; default 0).

    Returns
    -------
    BeliefPath
        K - advance steps from (x0, P0); not checked here (:func:`replan`
        builds a verified warm start from it).

    Raises
    ------
    ValidationError
        Bad ``previous`` or ``advance``.
    """
    path = previous.path if isinstance(previous, (SmoothResult, WarmStart)) else previous
    if not isinstance(path, BeliefPath):
        raise ValidationError("previous", f"must be a SmoothResult, WarmStart or BeliefPath, "
                                          f"got {type(previous).__name__}")
    if path.dim != scenario.dim:
        raise ValidationError("previous", f"its path has dimension {path.dim}, the scenario {scenario.dim}")
    if isinstance(advance, (bool, np.bool_)) or not isinstance(advance, (int, np.integer)) \
            or not 0 <= advance < path.K:
        raise ValidationError("advance", f"must be an integer in [0, {path.K - 1}] (the previous path has "
                                         f"{path.K} steps), got {advance!r}")
    x = np.vstack([np.asarray(scenario.x0, float)[None], path.x[advance + 1:]])
    S = np.asarray(path.S, float)[advance + 1:]
    return BeliefPath.from_sensing(x, scenario.P0, S, W=scenario.W)


def replan(scenario: Scenario, previous: SmoothResult | BeliefPath | WarmStart, advance: int = 0,
           method: Any = DEFAULT_METHOD, **kwargs: Any) -> SmoothResult:
    """Smooth from ``scenario``'s start belief, warm started from ``previous``.

    Parameters
    ----------
    scenario : Scenario
        The problem with the robot's current belief as its start (x0, P0):
        e.g. ``scenario.with_options(x0=x_hat, P0=P_hat)``.
    previous : SmoothResult, WarmStart or BeliefPath
        The last plan (:func:`reanchor` moves it to the new start). A
        :class:`SmoothResult` of ``ipopt`` or ``auto`` also hands IPOPT
        its variables and multipliers (:attr:`SmoothResult.resume`): a few
        iterations instead of a new descent; one of ``ccp`` the horizon of
        its conic step (docs/performance.md, "Re-planning from a new
        belief"). A state goes only to a method whose ``resume`` option
        takes it.
    advance : int, optional
        Steps executed since ``previous`` (default 0); the horizon becomes
        ``previous.K - advance``. With the resume state the re-plan is
        solved on ``previous``'s graph (or conic step) with those steps
        frozen at the new start (:mod:`belief_nlp.model.nlp_prefix`,
        :mod:`belief_nlp.model.conic_prefix`): nothing is built for
        the shorter horizon (without a risk budget, whose levels depend on
        the horizon).
    method, **kwargs
        As :func:`belief_nlp.smooth` (``K`` is the re-anchored path's and
        may not be given).

    Returns
    -------
    SmoothResult
        As :func:`belief_nlp.smooth`; verified like every answer.

    Raises
    ------
    InfeasibleStartError
        When a re-anchored transition cannot be made clear (the new start
        too close to a hazard for the first step the previous plan took).
    ValidationError
        Bad ``previous`` or ``advance``, or a ``K`` given.
    """
    for name in ("K", "sensing"):
        if name in kwargs:
            raise ValidationError(name, "replan keeps the previous path's steps (minus advance) and its sensing; "
                                        "smooth reanchor(...) yourself to change them")
    # after executed steps the state's graph is read with them frozen (nlp_resume.advanced)
    resume = nlp_resume.advanced(previous.resume, advance) if isinstance(previous, SmoothResult) else None
    # the NLP's first stage starts from the last answer's variables and multipliers, CCP
    # from the conic step of its graph (the methods with the option "resume", when
    # their check takes this state: ipopt and auto IPOPT's, ccp any offset)
    m = method if isinstance(method, Method) else get_method(method) if isinstance(method, str) else None
    check = m.options["resume"].check if m is not None and "resume" in m.options else None
    if resume is not None and check is not None and check(resume) is None:
        kwargs.setdefault("resume", resume)
    # the driver builds the warm start (with a risk budget's level, its K fallback)
    return smooth(scenario, reanchor(scenario, previous, advance), method=method, sensing="path", **kwargs)
