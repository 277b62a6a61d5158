"""What every smoothing method receives: the model, an exactly safe start,
the limits, and the shared safety check and history.

A method's ``run(problem, **options)`` iterates, calls :meth:`SmoothingProblem.check`
on each candidate point, :meth:`SmoothingProblem.record` once per iteration,
and returns an :class:`Outcome`. The driver (:mod:`.driver`) then chooses the
answer -- the method's point if it is exactly safe, verified and not above the
warm start, else the best accepted iterate, else the warm start -- so every
method reports in the same terms (docs/architecture.md, "The contract").
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..geometry import PolytopeSet, transition_minimiser
from ..model import BeliefModel, Layout
from ..scenario import Scenario
from .policy import DEFAULT_POLICY, SafetyPolicy
from .result import IterationRecord
from .warmstart import WarmStart, segment_certificates

__all__ = ["Check", "Outcome", "SmoothingProblem"]


def _digest(z: Layout) -> bytes:
    """A digest of the point's arrays (what :meth:`SmoothingProblem.check` reads)."""
    h = hashlib.blake2b(digest_size=16)
    for a in (z.x, z.Q, z.S, z.lam) + (() if z.tau is None else (z.tau,)):
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode() + a.tobytes())
    return h.digest()


def _require_finite(z: Layout) -> None:
    """ValueError unless every entry of the point is finite (never safe then)."""
    if not all(np.all(np.isfinite(a)) for a in (z.x, z.S, z.Q, z.lam)):
        raise ValueError("non-finite point")


@dataclass
class Check:
    """Certified safety of a point (docs/safety.md).

    margin : the proof -- min over transitions and hazards of the point's own
        Theorem-1 certificate values minus chi2 (closed form, both ends; a
        rigorous lower bound on the continuous-time squared Mahalanobis
        clearance minus chi2; transition 1's minus the start's own level
        chi2_start, ``Scenario.start_confidence``).
    upper : the exact 1-D minimisation's value minus chi2 (an upper bound,
        attained at some s); margin <= upper up to rounding. Not part of the
        proof: computed when first read (``upper_of``), NaN if it cannot be.
    target : smallest containment margin of the final posterior (scaled length).
    accept : the margin the policy requires (a fraction of chi2, absolute).
    point : the point, with certificates repaired where its own failed.
    """

    point: Layout
    margin: float
    target: float
    upper_of: Callable[[], float] | None = field(default=None, repr=False, compare=False)
    accept: float = 0.0
    target_accept: float = 0.0

    @functools.cached_property
    def upper(self) -> float:
        # the exact minimisation costs as much as the rest of a check and no method reads it
        try:
            return float("nan") if self.upper_of is None else float(self.upper_of())
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            return float("nan")

    @property
    def safe(self) -> bool:
        # NaN compares False: never safe
        return bool(self.margin >= self.accept and self.target >= self.target_accept)


@dataclass
class Outcome:
    """What a method's ``run`` returns to the driver.

    Parameters
    ----------
    status : str
        One of :data:`~belief_nlp.STATUSES` (``"converged"``, ``"max_iter"``, ...).
    message : str
        One sentence saying what happened, for :attr:`SmoothResult.message`.
    point : Layout or None, optional
        The method's answer in the model's layout (scaled units); None lets
        the driver take the best accepted iterate of the history.
    solver : str, optional
        The solver that ran (for :attr:`SmoothResult.solver`).
    stats : dict, optional
        Raw solver statistics (return status, iterations, times, ...).
    label : str, optional
        What answered, when not the method's name (e.g. ``"auto:ccp"``).
    resume : dict, optional
        State a later call can start from (:attr:`SmoothResult.resume`; the
        NLP methods: the first stage's variables and multipliers).
    """

    status: str
    message: str
    point: Layout | None = None
    solver: str = ""
    stats: dict = field(default_factory=dict)
    label: str = ""          # what answered, when not the method's name (e.g. "auto:ccp")
    resume: dict | None = None


class SmoothingProblem:
    """One smoothing run as a method sees it.

    The driver (:func:`belief_nlp.smooth`) builds it and hands it to the
    method's ``run(problem, **options)``; a method iterates from
    :attr:`start`, tests candidates with :meth:`check` and reports each
    iteration with :meth:`record` (docs/architecture.md, "The contract").

    Parameters
    ----------
    scenario : Scenario
        The planning problem.
    warm : WarmStart
        The feasible warm start the run begins from.
    model : BeliefModel
        The symbolic model of the scenario at the warm start's horizon
        (:class:`belief_nlp.model.BeliefModel`, scaled units).
    max_iter : int
        Iteration limit of the run.
    tol : float
        Relative optimality tolerance.
    time_limit : float or None
        Wall-time budget in seconds from ``t0``; None for no limit.
    t0 : float
        ``time.perf_counter()`` when the run started.
    solver : str or None
        The solver the method should use (None: its default).
    solver_options : dict
        Options passed to that solver.
    progress : bool
        Show a progress bar (:meth:`progress_bar`).
    keep_iterates : bool
        Keep the path of every accepted iterate.
    callback : callable or None
        ``callback(record)`` after every iteration; returning True (or raising
        StopIteration, as with scipy.optimize) stops the run.
    method : str
        The method's name (for records and messages).
    policy : SafetyPolicy, optional
        The margins a point must keep to be accepted (docs/safety.md).

    Attributes
    ----------
    start : Layout
        The warm start's exactly safe point (certificates repaired where needed).
    cost0 : float
        Cost of ``start``.
    history : list of IterationRecord
        One record per iteration, the warm start first (iteration 0).
    hazards, hazards_scaled : PolytopeSet
        The scenario's hazards packed for batched checks, in metres and in
        the model's scaled units.
    """

    def __init__(self, scenario: Scenario, warm: WarmStart, model: BeliefModel, *, max_iter: int, tol: float,
                 time_limit: float | None, t0: float, solver: str | None, solver_options: dict,
                 progress: bool, keep_iterates: bool, callback: Callable | None, method: str,
                 policy: SafetyPolicy = DEFAULT_POLICY):
        self.scenario = scenario
        self.warm = warm
        self.model = model
        self.max_iter = int(max_iter)
        self.tol = float(tol)
        self.time_limit = time_limit
        self.t0 = t0
        self.solver = solver
        self.solver_options = dict(solver_options)
        self.progress = progress
        self.keep_iterates = keep_iterates
        self.callback = callback
        self.method = method
        self.hazards = PolytopeSet.cached(scenario.hazards)
        # the same hazards in the model's scaled units: the exact check runs there
        # (squared Mahalanobis distances are unit-free), no SI round trip per iterate
        s = model.data.sigma
        self.hazards_scaled = PolytopeSet.cached([(h.A, h.b / s) for h in scenario.hazards])
        self.policy = policy
        self._checks: OrderedDict = OrderedDict()   # digest -> (Check, digest of its point) (see check)
        chk = self.check(model.tighten(model.from_path(warm.path, warm.lam)))
        self.start = chk.point
        self.cost0, ctrl0, info0 = model.cost(self.start)
        self.history: list[IterationRecord] = [
            IterationRecord(0, self.cost0, ctrl0, info0, "warm_start", min_margin=chk.margin, kalman_gap=0.0)]
        self.points: dict[int, Layout] = {}      # accepted iterates kept (iteration -> point)
        self.stop_requested = False
        #: iterations a solver performed past its last record: a solve ended
        #: from outside (fatrop's watchdog) returns no point to record
        self.unrecorded_to = 0
        #: work to start when a solver first runs (:meth:`solver_started`):
        #: IPOPT's solve releases the GIL, so work started in a thread then
        #: overlaps it (auto's CCP step built while IPOPT solves)
        self.while_solving: list[Callable[[], object]] = []

    def solver_started(self) -> None:
        """Start the work :attr:`while_solving` holds (each job once)."""
        jobs, self.while_solving = self.while_solving, []
        for job in jobs:
            job()

    # ------------------------------------------------------------ budget
    @property
    def deadline(self) -> float | None:
        """The ``time.perf_counter()`` reading at which the run is out of time (None: no limit)."""
        return None if self.time_limit is None else self.t0 + self.time_limit

    def time_left(self) -> float | None:
        """Seconds left before :attr:`deadline` (negative once past it; None: no limit)."""
        return None if self.time_limit is None else self.deadline - time.perf_counter()

    def out_of_time(self) -> bool:
        """True once the time limit is reached; a method stops iterating then."""
        return self.time_limit is not None and time.perf_counter() >= self.deadline

    # ------------------------------------------------------------ safety
    def check(self, z: Layout) -> Check:
        """Certified safety of ``z`` (see :class:`Check`); :meth:`_check` on
        a point with the same content as one checked before returns that
        result (the check is a function of the point's arrays: the same
        proof, not computed again -- a method's answer is checked by the
        method, by auto and by the driver)."""
        key = _digest(z)
        hit, point_key = self._checks.get(key, (None, None))
        if hit is None or _digest(hit.point) != point_key:      # (a result whose point was changed since: again)
            hit = self._check(z)
            self._checks[key] = (hit, _digest(hit.point))
            while len(self._checks) > 8:
                self._checks.popitem(last=False)
        return hit

    def _check(self, z: Layout) -> Check:
        """Certified safety of ``z`` (see :class:`Check`). The exact
        minimisation over s gives each pair's optimal certificate; where the
        point's own certificate does not prove the policy's margin, it is
        replaced by that one (scaled to stay interior), so the proof is the
        best available; the others are kept (they are well scaled for the
        next convex step)."""
        D = self.model.data
        if D.budget is not None:
            return self._check_budget(z)
        accept = self.policy.accept * D.chi2
        try:
            _require_finite(z)
            if np.any(z.lam < 0):      # interior-point iterates sit ~1e-8 outside lam >= 0; a proof needs lam >= 0
                z = z.copy()
                z.lam = np.maximum(z.lam, 0.0)
            segments = self.model.segments(z)
            levels = D.collision_levels()             # chi2; transition 1 at the start's own level
            start, end = self.model.transition_margins(z)     # each against its transition's level
            out = z
            bad = ~(np.minimum(start, end) >= accept)
            if np.any(bad):
                out = z.copy()
                lam = segment_certificates(*segments, self.hazards_scaled, levels)
                out.lam = np.where(bad[..., None], lam, z.lam)
                start, end = self.model.transition_margins(out)
            lower = float(np.min(np.minimum(start, end)))
            target = float(np.min(self.model.target_margins(out)))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            return Check(z, float("nan"), float("nan"), accept=accept)
        hazards, seg = self.hazards_scaled, tuple(np.array(a) for a in segments)   # (views of z's means: copied)

        def upper() -> float:
            return float(np.min(transition_minimiser(*seg, hazards).dist2 - levels))
        return Check(out, lower if np.isfinite(lower) else float("nan"), target, upper, accept,
                     self.policy.target)

    def _check_budget(self, z: Layout) -> Check:
        """:meth:`check` under a risk budget (:mod:`belief_nlp.allocation`): the
        proof is the Boole sum of g over the pairs' certified clearances, and
        ``margin`` = chi2 (1 - sum / budget) (>= accept: within the budget).
        Where a pair's own certificate proves less than the exact minimum
        allows, the exact minimiser's certificate (scaled to stay interior)
        replaces it. The point's levels tau are kept when it has them (a
        solver's answer), else set to its clearances (capped at tau_hi)."""
        from ..allocation import tail

        D, model = self.model.data, self.model
        accept = self.policy.accept * D.chi2
        tau_lo, tau_hi = D.level_bounds
        try:
            _require_finite(z)
            out = z.copy()
            out.lam = np.maximum(out.lam, 0.0)
            segments = model.segments(out)
            tm = transition_minimiser(*segments, self.hazards_scaled)
            clear = model.clearances(out)
            # a pair beyond tau_hi carries no risk to speak of: proving more would only inflate its
            # certificate (lam* grows like distance / variance) and the next step's scaling with it
            weak = ~(clear >= np.minimum(0.99 * tm.dist2, tau_hi))
            if np.any(weak):
                level = np.maximum(np.minimum(0.999 * tm.dist2, 1.05 * tau_hi), 1e-9)
                lam = segment_certificates(*segments, self.hazards_scaled, level)
                trial = out.copy()
                trial.lam = np.where(weak[..., None], lam, out.lam)
                better = model.clearances(trial) > clear
                out.lam = np.where(better[..., None], trial.lam, out.lam)
                clear = model.clearances(out)
            total = float(np.sum(tail(clear)))
            # levels: the point's own (a solver's) where proven, else its clearances; within [tau_lo, tau_hi]
            proven = clear * (1 - 1e-9)                  # a level its certificate proves despite rounding
            # (a start 1e-3 inside every pair row: interior for IPOPT; the sum stays within the budget)
            tau = np.minimum(clear / (1 + 1e-3), tau_hi) if out.tau is None else np.minimum(out.tau, proven)
            if not np.sum(tail(tau)) <= D.budget:
                tau = np.minimum(proven, tau_hi)
            out.tau = np.clip(tau, tau_lo, tau_hi)
            margin = D.chi2 * (1.0 - total / D.budget)
            # (the exact minimum is computed here anyway: the weak pairs above need it)
            upper = D.chi2 * (1.0 - float(np.sum(tail(tm.dist2))) / D.budget)
            target = float(np.min(model.target_margins(out)))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            return Check(z, float("nan"), float("nan"), accept=accept)
        return Check(out, margin if np.isfinite(margin) else float("nan"), target, lambda: upper, accept,
                     self.policy.target)

    def repair(self, chk: Check) -> Check | None:
        """Restore exact feasibility lost to solver tolerance (violations ~1e-7).

        Adds sensing eta Y_k at every step (each posterior shrinks by 1 / (1 + eta))
        and re-derives the priors (Lemma 2): every ellipse after the first
        transition shrinks, clearances and target margins grow, at an
        information cost of about alpha/2 K d eta. Tries eta from 10x the
        deficit up to 1e-3; None when that does not suffice."""
        D = self.model.data
        deficit = max((chk.accept - chk.margin) / D.chi2, chk.target_accept - chk.target, 0.0)
        if not np.isfinite(deficit):
            return None
        eta = max(10 * deficit, 1e-9)
        z = chk.point
        while eta <= 1e-3:
            cand = z.copy()
            cand.S[1:] = cand.S[1:] + eta * z.Y[1:]
            new = self.check(self.model.tighten(cand))
            if new.safe:
                return new
            eta *= 10
        return None

    # ----------------------------------------------------------- history
    @property
    def iterations(self) -> int:
        """Iterations performed so far: the last record's number (a solver
        that reports only the end of each solve leaves gaps in the numbering),
        or more when a solve ended without a point (:attr:`unrecorded_to`)."""
        return max(self.history[-1].iteration if self.history else 0, self.unrecorded_to)

    def record(self, rec: IterationRecord, point: Layout | None = None) -> bool:
        """Append one iteration; keep ``point`` when the record is accepted
        (an exactly safe candidate for the answer). Returns True when the
        method should stop (the user's callback asked, or time is up)."""
        self.history.append(rec)
        if point is not None and rec.accepted:
            self.points[rec.iteration] = point
        if self.callback is not None and not self.stop_requested:     # asked once: not called again
            try:
                stop = self.callback(rec)
            except StopIteration:           # scipy.optimize's way to stop from a callback
                stop = True
            if stop:
                self.stop_requested = True
        return self.stop_requested or self.out_of_time()

    def progress_bar(self, desc: str) -> Any:
        """A progress bar over ``max_iter`` when progress was asked for, else None
        (tqdm on a terminal or in Jupyter, periodic log lines otherwise)."""
        if not self.progress:
            return None
        from .._progress import progress_bar

        return progress_bar(self.max_iter, desc, "it")
