"""Switched-off sensing back on where it lowers the cost: rounds of the polish.

The polish fixes at 0 the columns of L_k that the floored stage held at its
floor, so its answer is a KKT point of the NLP with those columns held. It
is stationary for the problem in S only when every such step's block of the
Lagrangian's Hessian, 2 G_k, is positive semidefinite
(:mod:`.nlp_stationary`). Where one is not, sensing S_k + t v v^T along the
block's eigenvector v of its smallest eigenvalue w lowers the Lagrangian at
the rate w / 2. A round turns the column of the most negative block whose
rate pays (:data:`BENEFIT`) back on at floor * v, its entries free, and
runs the polish again from the answer and its multipliers; its answer is
taken when it converged, is exactly safe and is not costlier. Rounds stop
at an answer without such a column, at a round that does not give one, or
after ``rounds``. A re-plan on a longer graph (frozen steps) keeps its
sensing pattern: no rounds there.

Measured (docs/numerics.md, "Sensing back on after the polish"): one column
a round. Every negative column at once (11-25 steps of one unsensed
stretch) ran each round to the polish's cap at K = 80, as did one column
started at 5 or 20 times the floor.
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from ..model.nlp_form import NLPProblem
from ..model import Layout
from ..smoother.context import SmoothingProblem
from .nlp_stage import Stage
from .nlp_stationary import descent_columns

__all__ = ["reenter", "pays"]

log = logging.getLogger("belief_nlp.smoother")

#: a column comes back on only when the Lagrangian falls along its sensing by at
#: least this share of the sensing's direct price (:func:`_worth`). Measured
#: (alpha = 1): rounds that lowered the cost had shares 0.056-3.6; shares of
#: 0.007-0.012 lowered it by < 1e-6 relative in 6 iterations or crawled to the
#: polish's cap (docs/numerics.md, "Sensing back on after the polish")
BENEFIT = 0.02


def reenter(problem: SmoothingProblem, polish: Stage, floor: float, rounds: int,
            solve: Callable[[Callable, tuple, int], Stage], cap: int, left: int) -> int:
    """At most ``rounds`` rounds (module doc) after ``polish``, merged into it
    (attempts, iterations, answer); ``solve(bounds, duals, max_iter)`` runs
    one polish stage with ``bounds(nlp, point) -> (z0, lbz, ubz)`` from the
    multipliers ``duals``. A round gets at most ``cap`` iterations, all
    rounds together ``left``. Returns the number of rounds whose answer was
    taken."""
    taken = 0
    for _ in range(max(int(rounds), 0)):
        if problem.out_of_time() or problem.stop_requested or min(cap, left) <= 0:
            break
        cols = _paying(problem, polish)
        if not cols:
            break
        k, idx, v, w = min(cols, key=lambda c: c[3])
        z_prev = polish.z

        def bounds(nlp_: NLPProblem, lay: Layout, idx=idx, v=v, z_prev=z_prev) -> tuple:
            z0, lbz, ubz = nlp_.switch_off(np.clip(z_prev, nlp_.lbz, nlp_.ubz), nlp_.lbz, nlp_.ubz, floor)
            z0[idx] = floor * v
            lbz[idx], ubz[idx] = nlp_.lbz[idx], nlp_.ubz[idx]
            return z0, lbz, ubz

        more = solve(bounds, polish.duals, min(cap, left))
        left -= more.used
        log.info("sensing back on at step %d (eigenvalue %.3g): %s after %d iterations, cost %.6g -> %s", k + 1, w,
                 more.status, more.used, polish.answer[0], "-" if more.answer is None else f"{more.answer[0]:.6g}")
        take = more.answer is not None and more.answer[0] <= polish.answer[0]
        polish.absorb(more, take)
        if not take:
            break
        taken += 1
    return taken


def pays(problem: SmoothingProblem, polish: Stage) -> bool:
    """Whether ``polish``'s answer has a switched-off column whose sensing
    pays: the rounds' own test, e.g. after rounds that did not turn it on."""
    return bool(_paying(problem, polish))


def _paying(problem: SmoothingProblem, polish: Stage) -> list:
    """The switched-off columns of ``polish``'s answer whose sensing pays
    (:func:`_worth` of :func:`.nlp_stationary.descent_columns`); none
    without an answer and its solve."""
    if polish.answer is None or polish.solved is None or polish.z is None or polish.duals is None:
        return []
    nlp, solver, p = polish.solved
    return _worth(nlp, polish.z, problem.model.data.alpha, descent_columns(nlp, solver, p, polish.z, polish.duals[1]))


def _worth(nlp: NLPProblem, z: np.ndarray, alpha: float, cols: list) -> list:
    """The columns of ``cols`` (:func:`.nlp_stationary.descent_columns`)
    whose sensing pays: the Lagrangian's rate along v v^T, w / 2, below
    -BENEFIT times the direct price of that sensing, alpha / 2 v^T Y_k^-1 v
    (the information term's own gradient in S_k)."""
    if not cols:
        return []
    lay = nlp.unpack(z)
    out = []
    for c in cols:
        k, _, v, w = c
        Y = np.asarray(lay.Q[k + 1] + lay.S[k + 1], float)
        u = np.zeros(Y.shape[0])
        u[Y.shape[0] - v.size:] = v                    # column j's entries are rows j..d-1
        price = 0.5 * alpha * float(u @ np.linalg.solve(Y, u))
        if -0.5 * w >= BENEFIT * price:
            out.append(c)
    return out
