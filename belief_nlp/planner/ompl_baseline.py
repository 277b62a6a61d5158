"""The OMPL baseline: a standard planner for the mean path, then minimum sensing.

``plan(scenario, planner="ompl:RRTstar")`` (any geometric planner of OMPL by
its class name) plans the *mean* path with OMPL and turns it into a belief
path the way any user path is turned into one (:func:`belief_nlp.warm_start`
with one step per edge and the least sensing that keeps every transition
clear). It answers the question "is planning in belief space better than a
standard planner followed by smoothing?" with the same geometry on both sides.

What OMPL is told
-----------------
* **State space**: R^d inside the domain's bounding box; the objective is
  OMPL's path length (a standard planner knows nothing of sensing).
* **State validity**: a transition can end there: the ellipse of the least
  covariance at the end of a step, ``E(x, P_floor + W)``, is clear of every
  obstacle and wall (:meth:`CollisionChecker.shrink_exponent` is 0); the
  start state with its ``P0``. (Goal samples offered to OMPL pass it too:
  the bidirectional planners grow a tree from them.)
* **Motion validity** (checked exactly, never sampled): the transition
  ``x_a -> x_b`` with the scenario's per-step noise ``W`` is certified clear
  by the IG-RRT* planner's own :class:`~.collision.CollisionChecker` (paper
  Theorem 1 in continuous time) from the near-exact posterior
  ``P_floor = eps W`` -- the most any sensing before the step can achieve
  (from the start state: the scenario's ``P0``, which cannot be changed).
  OMPL may reuse a motion's verdict for the reverse motion (RRT*'s rewiring
  does when the objective is symmetric) and the transition's noise grows
  along it, so a motion is valid only when it is clear in *both* directions.
* **Goal**: the mean strictly inside the target (``E(x, P_floor)`` inside);
  the final posterior can always be sensed down into it.

Every motion OMPL accepts can therefore be made clear by sensing before it,
and the warm start finds the least such sensing by halving the posterior
(its own exact checks and :func:`belief_nlp.verify` confirm the result).

The run is time-bounded (``time_limit``, default 1 s) like every OMPL
planner; it is not reproducible run to run (OMPL seeds its generators per
process, and what it does depends on the clock). ``seed`` drives the goal
sampler only. ``cost_trace`` holds OMPL's best path length over time for
planners that report it (``bestCost``: the RRT* family); the returned
``cost`` is the belief path's planner cost, travel + alpha * information
(nats), as for IG-RRT*.
"""

from __future__ import annotations

import gc
import logging
import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._limits import MAX_ALPHA
from ..errors import SolverError, ValidationError
from ..path import BeliefPath
from ..scenario import Scenario
from .collision import CollisionChecker
from .options import _is_int, _real
from .result import PlanResult

__all__ = ["OMPLOptions", "MeanPathValidity", "plan_ompl", "parse_planner", "ompl_planners", "resolve_ompl_options",
           "DEFAULT_PLANNER", "OMPL_PREFIX", "THREADED"]

log = logging.getLogger("belief_nlp.planner")

#: The default planner's name in ``plan(planner=...)`` and in study files.
DEFAULT_PLANNER = "igrrt"
#: Prefix of OMPL planner names: ``"ompl:RRTstar"``.
OMPL_PREFIX = "ompl:"
_FLOOR = 1e-9            # P_floor = _FLOOR * W: the near-exact posterior (as allocate_steps)
_INSTALL = "pip install 'belief-nlp[ompl]'"
_GOAL_SAMPLES = 16       # goal states offered to OMPL, drawn once per run from the target
_GOAL_THRESHOLD = 1e-12  # distanceGoal is 0 exactly in the target, >= 2e-12 elsewhere


def _import_ompl():
    """(ompl.base, ompl.geometric, ompl.util), or SolverError saying how to install them."""
    try:
        from ompl import base as ob, geometric as og, util as ou
    except ImportError as exc:
        raise SolverError(f"the OMPL baseline needs the 'ompl' package (OMPL >= 2.0), which is not importable "
                          f"({exc}); install the extra: {_INSTALL}") from None
    return ob, og, ou


#: OMPL planners that call the validity checker from threads of their own: with
#: a Python checker they deadlock on the interpreter lock, so they are refused.
THREADED = ("AnytimePathShortening", "CForest", "PRM", "PRMstar", "SPARS", "SPARStwo", "XXL", "pRRT", "pSBL")


def ompl_planners() -> list[str]:
    """Names (``"ompl:<Class>"``) of the usable geometric planners of the installed OMPL
    (all but the multi-threaded ones, :data:`THREADED`)."""
    ob, og, _ = _import_ompl()
    return sorted(OMPL_PREFIX + n for n in dir(og)
                  if isinstance(getattr(og, n), type) and issubclass(getattr(og, n), ob.Planner)
                  and n not in THREADED)


def parse_planner(name: Any) -> str | None:
    """None for IG-RRT* (``"igrrt"``), the OMPL class name for ``"ompl:<Class>"``.

    Names are case-insensitive (``"OMPL:rrtstar"`` is ``"ompl:RRTstar"``).
    Anything else raises :class:`~belief_nlp.errors.ValidationError` naming
    the field ``planner``; an OMPL name is checked against the installed OMPL
    (a missing package raises :class:`~belief_nlp.errors.SolverError`).
    """
    lower = name.lower() if isinstance(name, str) else None
    if lower is None or not (lower == DEFAULT_PLANNER or lower.startswith(OMPL_PREFIX)):
        raise ValidationError("planner", f"must be {DEFAULT_PLANNER!r} (IG-RRT*) or 'ompl:<planner>' such as "
                                         f"'ompl:RRTstar', got {name!r:.60}")
    if lower == DEFAULT_PLANNER:
        return None
    cls = name[len(OMPL_PREFIX):]
    if cls.lower() in {t.lower() for t in THREADED}:
        raise ValidationError("planner", f"{name!r} runs threads of its own, which cannot call this library's "
                                         f"(Python) validity checks; choose another, e.g. 'ompl:RRTstar'")
    known = {n.lower(): n for n in ompl_planners()}
    if OMPL_PREFIX + cls.lower() not in known:
        raise ValidationError("planner", f"{name!r} is not a geometric planner of the installed OMPL; known: "
                                         f"{', '.join(sorted(known.values()))}")
    return known[OMPL_PREFIX + cls.lower()][len(OMPL_PREFIX):]


@dataclass(frozen=True)
class OMPLOptions:
    """Options of the OMPL baseline (validated by :func:`resolve_ompl_options`).

    Attributes
    ----------
    planner : the OMPL class name (``"RRTstar"``).
    seed : seed of the goal sampler (OMPL's own generators are seeded by OMPL).
    alpha : information weight of the reported cost; None takes the scenario's.
    time_limit : seconds of planning (OMPL planners are time-bounded).
    range : the planner's maximum motion length (``setRange``), m; None: OMPL's default.
    goal_bias : probability of sampling the goal (``setGoalBias``); None: OMPL's default.
    safety_margin : relative margin on chi2 of every clearance decision, as IG-RRT*'s.
    """

    planner: str
    seed: int | None = 0
    alpha: float | None = None
    time_limit: float = 1.0
    range: float | None = None
    goal_bias: float | None = None
    safety_margin: float = 1e-6

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return asdict(self)


#: IG-RRT* options that have a single meaning here (any other value is refused).
_FIXED = {"metric": "entropy", "noise": "per_step", "info_unit": "nats"}


def resolve_ompl_options(planner: str, scenario_alpha: float, **kwargs: Any) -> OMPLOptions:
    """Validate the keywords of an OMPL run; faults raise ValidationError naming the option."""
    known = {"seed", "alpha", "time_limit", "range", "goal_bias", "safety_margin"}
    o: dict[str, Any] = {}
    for key, value in kwargs.items():
        if key in _FIXED:
            if value is not None and value != _FIXED[key]:
                raise ValidationError(key, f"the OMPL baseline plans with {key}={_FIXED[key]!r} (the smoother's "
                                           f"model), got {value!r:.40}")
            continue
        if key not in known:
            raise ValidationError(key, f"not an option of the OMPL planners (IG-RRT* only?); known: "
                                       f"{', '.join(sorted(known | set(_FIXED)))}")
        if value is not None:
            o[key] = value
    seed = o.get("seed", 0)
    if seed is not None and (not _is_int(seed) or int(seed) < 0):
        raise ValidationError("seed", f"must be a non-negative integer or None, got {seed!r:.40}")
    alpha = o.get("alpha")
    return OMPLOptions(
        planner=planner,
        seed=None if seed is None else int(seed),
        alpha=float(scenario_alpha) if alpha is None else _real("alpha", alpha, 0.0, MAX_ALPHA),
        time_limit=_real("time_limit", o.get("time_limit", 1.0), 0.0, 1e6, low_open=True),
        range=None if "range" not in o else _real("range", o["range"], 0.0, low_open=True),
        goal_bias=None if "goal_bias" not in o else _real("goal_bias", o["goal_bias"], 0.0, 1.0),
        safety_margin=_real("safety_margin", o.get("safety_margin", 1e-6), 0.0, 0.1))


class MeanPathValidity:
    """The exact validity tests OMPL is given (see the module docstring).

    Counts every decision in ``stats``; usable without OMPL (the tests call it
    on plain arrays).
    """

    def __init__(self, scenario: Scenario, safety_margin: float):
        self.scenario = scenario
        self.checker = CollisionChecker(scenario, safety_margin)
        self.W = np.asarray(scenario.W, float)
        self.P_floor = _FLOOR * self.W
        self.P_end = self.P_floor + self.W
        self.x0 = np.asarray(scenario.x0, float)
        self.P0 = np.asarray(scenario.P0, float)
        self.stats = {"state_checks": 0, "motion_checks": 0, "motions_valid": 0}

    def state_valid(self, x: np.ndarray) -> bool:
        """A motion can end here: the ellipse of ``P_floor + W`` (the least covariance at the
        end of a transition) is clear; at the start, that of ``P0``."""
        self.stats["state_checks"] += 1
        P = self.P0 if np.array_equal(x, self.x0) else self.P_end
        return self.checker.shrink_exponent(x, P) == 0

    def motion_valid(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Both directions a -> b and b -> a are certified clear from the near-exact posterior
        (only start -> other when one end is the start: the path never returns there)."""
        self.stats["motion_checks"] += 1
        if np.array_equal(b, self.x0):
            a, b = b, a
        if np.array_equal(a, self.x0):
            x0, x1, P = a[None], b[None], self.P0[None]
        else:
            x0, x1 = np.stack([a, b]), np.stack([b, a])
            P = np.stack([self.P_floor, self.P_floor])
        W = np.broadcast_to(self.W, P.shape)
        ok = bool(np.all(self.checker.transitions_clear(x0, np.ascontiguousarray(P), x1, np.ascontiguousarray(W))))
        self.stats["motions_valid"] += ok
        return ok

    def in_target(self, x: np.ndarray) -> bool:
        """The mean strictly inside the target (its near-exact ellipse is)."""
        return self.checker.in_target(x, self.P_floor)


def _setup(ob, og, sc: Scenario, opts: OMPLOptions, validity: MeanPathValidity):
    """SpaceInformation, ProblemDefinition and planner for one run."""
    d = sc.dim
    lo, hi = sc.domain.bounding_box()
    space = ob.RealVectorStateSpace(d)
    bounds = ob.RealVectorBounds(d)
    for i in range(d):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def vec(state) -> np.ndarray:
        return np.array([state[i] for i in range(d)])

    si.setStateValidityChecker(lambda s: validity.state_valid(vec(s)))

    class _Motions(ob.MotionValidator):
        def checkMotion(self, s1, s2) -> bool:  # noqa: N802 - OMPL's name
            return validity.motion_valid(vec(s1), vec(s2))

    motions = _Motions(si)
    si.setMotionValidator(motions)
    si.setup()
    # A finite set of goal samples: the informed and bidirectional planners
    # (InformedRRTstar, AORRTC, RRTConnect) collect every goal sample OMPL offers.
    rng = np.random.default_rng(opts.seed)
    tlo, thi = sc.target.bounding_box()
    cand = rng.uniform(tlo, thi, size=(64 * _GOAL_SAMPLES, d))
    goals = [x for x in cand if validity.in_target(x) and validity.state_valid(x)][:_GOAL_SAMPLES]
    if not goals:
        raise ValidationError("target", "no mean inside the target can end a transition (the noise W of one "
                                        "step does not fit between the target's neighbours)")

    class _Target(ob.GoalSampleableRegion):
        def distanceGoal(self, state) -> float:  # noqa: N802
            x = vec(state)
            if validity.in_target(x):
                return 0.0
            # OMPL's test is distance < threshold: outside gets at least twice the threshold
            return max(float(np.max(sc.target.A @ x - sc.target.b)), 2 * _GOAL_THRESHOLD)

        def sampleGoal(self, state) -> None:  # noqa: N802
            x = goals[int(rng.integers(len(goals)))]
            for i in range(d):
                state[i] = float(x[i])

        def maxSampleCount(self) -> int:  # noqa: N802
            return len(goals)

        def couldSample(self) -> bool:  # noqa: N802
            return True

    goal = _Target(si)
    goal.setThreshold(_GOAL_THRESHOLD)
    pdef = ob.ProblemDefinition(si)
    start = si.allocState()
    for i in range(d):
        start[i] = float(sc.x0[i])
    pdef.addStartState(start)
    pdef.setGoal(goal)
    pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    planner = getattr(og, opts.planner)(si)
    if opts.range is not None:
        if not hasattr(planner, "setRange"):
            raise ValidationError("range", f"OMPL's {opts.planner} has no range setting")
        planner.setRange(opts.range)
    if opts.goal_bias is not None:
        if not hasattr(planner, "setGoalBias"):
            raise ValidationError("goal_bias", f"OMPL's {opts.planner} has no goal bias setting")
        planner.setGoalBias(opts.goal_bias)
    planner.setProblemDefinition(pdef)
    planner.setup()
    # keep the Python objects OMPL calls back alive for the run
    return si, pdef, planner, (space, bounds, motions, goal, start)


def _solve(ob, og, ou, sc: Scenario, opts: OMPLOptions, validity: MeanPathValidity, t_start: float):
    """Run OMPL: (means or None, cost trace, status text, solve seconds, iterations or None)."""
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_WARN)     # OMPL informs on stdout for every run otherwise
    try:
        si, pdef, pl, _alive = _setup(ob, og, sc, opts, validity)
        trace: list[list[float]] = []
        best_cost = getattr(pl, "bestCost", None)

        def stop() -> bool:
            now = time.perf_counter() - t_start
            if best_cost is not None:
                c = best_cost().value()
                if math.isfinite(c) and (not trace or c < trace[-1][1]):
                    trace.append([now, c])
            return now >= opts.time_limit

        t_solve = time.perf_counter()
        status = str(pl.solve(ob.PlannerTerminationCondition(stop)))
        solve_time = time.perf_counter() - t_solve
        best_cost = None     # the planner may keep `stop`: break the cycle planner -> stop -> planner
        x = None
        if pdef.hasExactSolution():
            x = np.array([[s[i] for i in range(sc.dim)] for s in pdef.getSolutionPath().getStates()])
            length = float(np.sum(np.linalg.norm(np.diff(x, axis=0), axis=1)))
            if not trace or trace[-1][1] > length * (1 + 1e-9):
                trace.append([time.perf_counter() - t_start, length])
        iterations = int(pl.numIterations()) if hasattr(pl, "numIterations") else None
        # drop OMPL's references to our Python callbacks
        pl.clear()
        pdef.clearSolutionPaths()
        pdef.clearGoal()
        pdef.clearStartStates()
    finally:
        ou.setLogLevel(level)
    return x, trace, status, solve_time, iterations


def plan_ompl(scenario: Scenario, planner: str, **options: Any) -> PlanResult:
    """Plan the mean path with OMPL's ``planner`` (class name), attach minimum sensing.

    Called by :func:`belief_nlp.plan` for ``planner="ompl:<Class>"``;
    ``options`` as :class:`OMPLOptions` (plus ``metric``, ``noise``,
    ``info_unit`` at their only values). See the module docstring.
    """
    from ..errors import InfeasibleStartError
    from ..smoother.warmstart import warm_start

    ob, og, ou = _import_ompl()
    opts = resolve_ompl_options(planner, scenario.alpha, **options)
    sc = scenario
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    validity = MeanPathValidity(sc, opts.safety_margin)
    x, trace, status, solve_time, iterations = _solve(ob, og, ou, sc, opts, validity, t_start)
    # OMPL's objects and our callbacks form reference cycles through C++; collect them
    # now, else nanobind reports them as leaked when the interpreter exits.
    gc.collect()
    stats = {"planner": f"{OMPL_PREFIX}{opts.planner}", "ompl_status": status, "objective": "path length",
             **validity.stats}
    if iterations is not None:
        stats["iterations"] = iterations
    timings = {"solve": solve_time}
    common = dict(alpha=opts.alpha, metric="entropy", info_unit="nats", noise="per_step",
                  cost_history=np.array([c for _, c in trace]), first_solution_iteration=None, tree=None,
                  stats=stats, timings=timings, options=opts.to_dict(), seed=opts.seed, scenario=sc.name,
                  planner=f"{OMPL_PREFIX}{opts.planner}", cost_trace=trace)

    def failed(message: str) -> PlanResult:
        timings["total"] = time.perf_counter() - t_start
        timings["cpu"] = time.process_time() - cpu_start
        log.info("OMPL %s failed: %s", opts.planner, message)
        return PlanResult(success=False, message=message, path=None, cost=math.inf, travel=math.nan,
                          information=math.nan, verification=None, **common)

    if x is None:
        return failed(f"OMPL {opts.planner} found no exact solution in {opts.time_limit:g} s ({status})")
    meta = {"planner": f"{OMPL_PREFIX}{opts.planner}", "scenario": sc.name, "seed": opts.seed,
            "options": opts.to_dict(), "source": f"OMPL {opts.planner} mean path"}
    # No sensing yet: the warm start adds the least that makes every transition clear.
    unsensed = BeliefPath.from_sensing(x, sc.P0, np.zeros((x.shape[0] - 1, sc.dim, sc.dim)), W=sc.W,
                                       noise="per_step", meta=meta)
    t0 = time.perf_counter()
    try:
        ws = warm_start(sc, unsensed, K=None, sensing="minimal")
    except InfeasibleStartError as exc:
        return failed(f"OMPL {opts.planner}'s path cannot carry a safe belief: {exc}")
    timings["sensing"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    timings["cpu"] = time.process_time() - cpu_start
    path = ws.path
    cost = path.planner_cost(opts.alpha)
    log.info("OMPL %s done: length %.4g m, cost %.6g in %.3g s", opts.planner, path.length, cost, timings["total"])
    return PlanResult(success=True, message=f"path found ({status} after {solve_time:.3g} s)", path=path, cost=cost,
                      travel=path.length, information=path.information, verification=ws.report.to_dict(), **common)
