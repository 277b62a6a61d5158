"""The floor stepped down after a polish that ends without an answer.

The floored stage keeps L_ii >= floor, so its answer senses at least
floor^2 along every axis of every step. The polish switches that sensing
off (:meth:`NLPProblem.switch_off`). On a long path the floor's sensing can
bear load together: switched off everywhere at once, it leaves the polish's
start far from feasible (0.49 in the rows at K = 80), and the polish runs to
its cap without an answer. The run's answer is then the floored one, which
pays for the floor (up to 2.7 % at K = 80).

The same holds where the polish answers but sensing at a switched-off
stretch would pay and the re-entry rounds (:mod:`.nlp_reentry`), one
column at a time, do not turn it on (random-polygons map 0 at K = 80: a
round over steps 72-76 ran to its cap).

A step-down runs the floored stage once more at ``floor * factor``, resumed
from its answer and multipliers with the backend's resume options (those of
a re-plan), the floor's multipliers released (:func:`released`), then the
polish at that floor from its answer (or, when the lower stage stopped
short, from its best exactly safe point below the first's, with the
stage's last multipliers). What bears load stays on above the lower floor
as real sensing; the rest falls to it and is switched off. The polish's
answer is taken when it converged and is exactly safe and not costlier;
otherwise the lower stage's answer or best point is the polish's best
point when lower.

Measured on the issue-21 protocol (docs/numerics.md, "The floor stepped
down"): the polish had no answer in 8 of 184 cases per method (6 of 12 at
K = 80); stepped down by 0.1, all 8 polished, 0.4-2.9 % lower, stationary
in S, none above auto's CCP polish; after the rounds, the one case at
K = 80 polished 0.6 % lower. The lower stage took 10-81 iterations,
and one crawled to its cap of twice the polish's next to its best point
(a cap of the polish's own left one of the 8 unpolished).
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from ..model.nlp_form import NLPProblem
from ..smoother.context import SmoothingProblem
from .nlp_stage import Stage

__all__ = ["STEP_DOWN", "step_down", "released"]

log = logging.getLogger("belief_nlp.smoother")

#: the default ``step_down``: the lower floor's factor (0: no step-down)
STEP_DOWN = 0.1


def step_down(problem: SmoothingProblem, first: Stage, polish: Stage, floor: float, factor: float,
              solve: Callable[..., Stage], lower_opts: dict, polish_opts: dict, cap: int, left: int) -> str | None:
    """The step-down to ``floor * factor`` (module doc) after ``polish``
    (without an answer, or with one whose switched-off sensing would pay),
    merged into it: its attempts and iterations; the lower polish's answer
    when taken (not costlier than any before), else, for a polish without
    an answer, a lower best point. ``solve(**kw)`` runs one attempt of a
    stage (:func:`.nlp_engine._solve_stage`'s keywords); ``lower_opts``:
    the plug-in's options of the lower floored stage, ``polish_opts`` of its
    polish. The lower stage gets at most 2 ``cap`` iterations, the polish
    ``cap``, both together ``left``. Returns None when it did not run, else
    "polished" (the lower polish answered), "floored" (the lower floored
    stage's answer or best point is the polish's best, lower than any
    before) or "not lower"."""
    if not factor or first.answer is None or first.z is None or first.duals is None or first.solved is None \
            or problem.out_of_time() or problem.stop_requested or min(cap, left) <= 0:
        return None
    before = min(first.answer[0], polish.best[0] if polish.best is not None else np.inf,
                 polish.answer[0] if polish.answer is not None else np.inf)
    lower, z_first = floor * factor, first.z
    duals = (released(first.solved[0], first.duals[0]), first.duals[1])
    down = solve(formulation="logchol", floor=lower, opts=lower_opts, start=first.answer[1],
                 max_iter=min(2 * cap, left), duals=duals,
                 bounds=lambda nlp, lay: (np.clip(z_first, nlp.lbz, nlp.ubz), nlp.lbz, nlp.ubz))
    polish.absorb(down, take=False)
    # the lower stage's answer, or its best point below the first's (seen: a crawl of
    # backtracking steps next to it), with the stage's last multipliers
    start = down.answer or (down.best if down.best is not None and down.best[0] < before else None)
    if start is not None and down.duals is not None and not problem.out_of_time() \
            and not problem.stop_requested and min(cap, left - down.used) > 0:
        again = solve(formulation="cholesky", floor=lower, opts=polish_opts, start=start[1],
                      max_iter=min(cap, left - down.used), duals=down.duals,
                      bounds=lambda nlp, lay: nlp.without_sensing(lay, lower))
        taken = again.answer is not None and again.answer[0] <= before
        polish.absorb(again, take=taken)
        if taken:
            log.info("floor stepped down to %g after the polish: polished", lower)
            return "polished"
    # (a polish with an answer keeps it: the run's answer is then that answer, not the best point)
    if start is not None and polish.answer is None and (polish.best is None or start[0] <= polish.best[0]):
        # (also when the lower polish's best is its start, the same point)
        what = "answer" if start is down.answer else "best exactly safe point"
        polish.best = (start[0], start[1], f"the floored stage's {what} at floor {lower:g}")
    outcome = "floored" if polish.answer is None and polish.best is not None and polish.best[0] < before \
        else "not lower"
    log.info("floor stepped down to %g after the polish: %s", lower, outcome)
    return outcome


def released(nlp: NLPProblem, lam_x: np.ndarray) -> np.ndarray:
    """``lam_x`` of a floored answer with the floor's multipliers (the lower
    bounds of L's diagonal) set to 0: at a lower floor those bounds are
    log(1 / factor) away, where complementarity puts their multipliers at
    ~mu / 2.3. Kept, they read as a dual infeasibility of their size: the
    first step of paper-multi at K = 80 went 223 long and into restoration."""
    K, tri, off = nlp.info["K"], nlp.info["tri"], nlp.info["sensing_offset"]
    diag = [p for p, (i, j) in enumerate(tri) if i == j]
    idx = off + (np.arange(K)[:, None] * len(tri) + np.array(diag)[None, :]).ravel()
    out = np.array(lam_x, float)
    out[idx] = np.maximum(out[idx], 0.0)          # CasADi's lam_x: negative at an active lower bound
    return out
