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
from numpy.typing import ArrayLike

from ..errors import ValidationError
from ..methods import nlp_resume
from ..path import BeliefPath
from ..polytope import _as_finite_array
from ..scenario import Scenario
from ..scenario_validate import _covariance, _is_real
from .driver import smooth
from .registry import DEFAULT_METHOD, Method, get_method
from .result import SmoothResult
from .warmstart import _START_MARGIN, WarmStart

__all__ = ["replan", "reanchor", "relaxed_start"]

#: relaxed_start's default: the start held to 98 % of its own squared clearance
RELAXED_START_MARGIN = 0.02


def relaxed_start(scenario: Scenario, x0: ArrayLike, P0: ArrayLike,
                  previous: SmoothResult | BeliefPath | WarmStart | None = None, advance: int = 0,
                  margin: float = RELAXED_START_MARGIN) -> Scenario:
    """``scenario`` from the start belief (x0, P0), its first transition held
    to a lower level when the scenario's own cannot be met from there.

    In a control loop the estimate moves by its error. Moved toward a
    hazard, its confidence ellipse may overlap it, or the step the last plan
    takes next may pass closer than the scenario's level allows: nothing --
    no plan, no sensing -- clears a first transition that starts there
    (Theorem 1 includes s = 0, and the end's prior P0 + W is data too).
    Such a start gets ``start_confidence`` = the level of (1 - margin) times
    d2, the smallest squared Mahalanobis clearance of the start ellipse and,
    with ``previous``, of the re-anchored first transition (to the mean
    :func:`reanchor` keeps). Transition 1 is certified at that level, every
    later one at the scenario's, so the plan is back at the nominal level
    after one step (docs/mpc.md). A start the scenario's level can be met
    from is left as it is.

    Parameters
    ----------
    scenario : Scenario
        The problem (without a risk budget, which prices the start itself).
    x0, P0 : array_like
        The start mean (d,) and covariance (d, d), as ``Scenario.x0`` / ``P0``.
    previous : SmoothResult, WarmStart or BeliefPath, optional
        The last plan, as :func:`replan` will be given it; None: the start
        ellipse alone decides.
    advance : int, optional
        Steps executed since ``previous``, as for :func:`replan`.
    margin : float, optional
        0 < margin < 1 (default 0.02): the room left between the level and
        the clearance, for the optimiser to move in.

    Returns
    -------
    Scenario
        ``scenario.with_options(x0=x0, P0=P0, start_confidence=...)``, None
        when the scenario's own level can be met.

    Raises
    ------
    ValidationError
        Bad ``margin``, x0, P0, ``previous`` or ``advance``, or a start whose
        mean (or first step) is on or inside a hazard: no level clears it.
    """
    from scipy.stats import chi2 as chi2_law

    from ..geometry import PolytopeSet, squared_mahalanobis_distance, transition_minimiser

    if not _is_real(margin) or not 0 < float(margin) < 1:
        raise ValidationError("margin", f"must lie strictly between 0 and 1, got {margin!r:.40}")
    x0 = _as_finite_array(x0, "x0", 1)
    if x0.size != scenario.dim:
        raise ValidationError("x0", f"must have {scenario.dim} entries, got {x0.size}")
    P0 = _covariance(P0, scenario.dim, "P0", allow_singular=True)
    hazards = PolytopeSet.cached(scenario.hazards)
    d2 = squared_mahalanobis_distance(x0[None], P0[None], hazards)[0]
    what = "start mean"
    if previous is not None:
        nxt = _path_of(previous, scenario, advance).x[advance + 1]
        d2t = transition_minimiser(x0[None], P0[None], nxt[None], scenario.W, hazards).dist2[0]
        if np.min(d2t) < np.min(d2):
            d2, what = d2t, "first step"
    j = int(np.argmin(d2))
    if d2[j] >= scenario.chi2 * (1 + _START_MARGIN):     # what the warm start needs at the scenario's level
        return scenario.with_options(x0=x0, P0=P0, start_confidence=None)
    if not d2[j] > 0:
        raise ValidationError("x0", f"the {what} is on or inside {scenario.hazards[j].name}: no level clears it")
    level = (1 - float(margin)) * float(d2[j])
    return scenario.with_options(x0=x0, P0=P0, start_confidence=float(chi2_law.cdf(level, scenario.dim)))


def _path_of(previous: SmoothResult | BeliefPath | WarmStart, scenario: Scenario, advance: int) -> BeliefPath:
    """``previous``'s path, checked as :func:`reanchor` checks it."""
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
    return path


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
    path = _path_of(previous, scenario, advance)
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
        belief"); one of ``fatrop`` or ``sqp`` its graph (they take no
        multipliers). A state goes only to a method whose ``resume`` option
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
        may not be given); ``resume=None`` ignores ``previous``'s state and
        builds the shorter horizon.

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
