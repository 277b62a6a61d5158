"""Whether a polished answer is stationary for the sensing it switched off.

The polish (:mod:`.nlp_engine`, stage 2) fixes at 0 every column of L_k that
the floored stage held at its floor: its converged answer is a KKT point of
the NLP *with those columns held*, not yet of the problem in S_k = L_k L_k^T,
where sensing may come back on. With G_k = dLagrangian/dS_k (the polish's
multipliers), adding sensing t v v^T at step k changes the Lagrangian by
t v^T G_k v, so the answer is stationary in S iff G_k >= 0 at every step
with a switched-off column (and G_k L_k = 0 elsewhere: the polish's own KKT
conditions). G_k needs no second form of the model: at a zero column l_j of
L_k the Lagrangian's Hessian block in that column's entries (rows j..d-1) is
2 G_k restricted to them, because S_k is quadratic in l_j and every other
term of the second derivative carries a factor l_j.

A CCP step from a point that is stationary in S returns that point (its
convex majorant has the same gradients there), so ``auto`` skips its CCP
polish after such an answer (docs/numerics.md, "Skipping the CCP polish at a
stationary answer"): on the issue-21 protocol the polish then lowered the
cost by at most 3.6e-5 relative, while every gain above 1e-4 followed a
polish that stopped at its iteration cap or a negative block.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..model.nlp_form import NLPProblem
from ..model.nlp_matrices import lower_stack

__all__ = ["sensing_stationary", "descent_columns"]


#: a column of L_k this short (scaled units; the floor is 1e-2) counts as off:
#: its block is 2 G_k up to O(|l_j|), and the polish's gradient in it, 2 G_k l_j,
#: says nothing about G_k (measured on 24 runs at K = 20: such columns at
#: 2e-24 .. 2.5e-9, none between that and the floor)
OFF = 1e-5


#: the last :func:`_off_blocks` call, [solver, p, z, lam_g, result]: one polished
#: answer is asked up to three times (the re-entry rounds, the step-down's test
#: after them, ``sensing_stationary``), each a Hessian evaluation
_LAST: list = []


def _off_blocks(nlp: NLPProblem, solver: Any, p: np.ndarray, z: np.ndarray, lam_g: np.ndarray):
    """The steps with a switched-off column, which columns are off, each such
    step's own Hessian block (its t entries of L) and whether the on columns
    before its first off column determine G_k; None when the solver has no
    Hessian function to ask. The same solver at equal arguments: the last
    result again."""
    p, z, lam_g = (np.asarray(a, float) for a in (p, z, lam_g))
    if _LAST and _LAST[0] is solver and all(np.array_equal(a, b) for a, b in zip(_LAST[1:4], (p, z, lam_g))):
        return _LAST[4]
    found = _blocks_of(nlp, solver, p, z, lam_g)
    _LAST[:] = [solver, p.copy(), z.copy(), lam_g.copy(), found]
    return found


def _blocks_of(nlp: NLPProblem, solver: Any, p: np.ndarray, z: np.ndarray, lam_g: np.ndarray):
    """:func:`_off_blocks` computed."""
    try:
        hess = solver.get_function("nlp_hess_l")
    except RuntimeError:
        return None
    tri, d, K, off = nlp.info["tri"], nlp.info["d"], nlp.info["K"], nlp.info["sensing_offset"]
    t = len(tri)
    L = lower_stack(z[off:off + K * t].reshape(K, t), tri, d)
    off_cols = np.linalg.norm(L, axis=1) <= OFF                  # (K, d): switched-off columns
    steps = np.flatnonzero(off_cols.any(axis=1))
    if steps.size == 0:
        return steps, off_cols, np.zeros((0, t, t)), np.zeros(0, bool)
    # E_j + span(on columns) = R^d for the first off column j iff the diagonal
    # of every column before it (all on; L is lower triangular) is nonzero
    first = off_cols[steps].argmax(axis=1)
    diag = np.abs(L[steps][:, np.arange(d), np.arange(d)])
    spans = ~np.any((np.arange(d)[None, :] < first[:, None]) & (diag <= OFF), axis=1)
    idx = (off + steps[:, None] * t + np.arange(t)[None, :]).ravel()
    # the steps' rows and columns cut in CasADi (half the time of the whole Hessian through scipy)
    sub = hess(z, p, 1.0, lam_g)[idx.tolist(), idx.tolist()].full()      # upper triangle
    sub = sub + sub.T - np.diag(np.diag(sub))
    n = steps.size
    blocks = sub.reshape(n, t, n, t)[np.arange(n), :, np.arange(n), :]       # (n, t, t): each step's own
    return steps, off_cols, blocks, spans


def _entries(nlp: NLPProblem, j: int) -> np.ndarray:
    """Positions of column j's entries (rows j..d-1) in a step's t entries of L."""
    return np.array([i for i, (_, c) in enumerate(nlp.info["tri"]) if c == j])


def sensing_stationary(nlp: NLPProblem, solver: Any, p: np.ndarray, z: np.ndarray, lam_g: np.ndarray) -> bool | None:
    """True when the "cholesky" NLP's answer ``z`` (``solver``, the nlpsol
    that gave it, its parameters ``p``, the rows' multipliers ``lam_g``) is
    stationary in S at every step with a switched-off column (module doc; a
    column shorter than :data:`OFF` counts as off); False when a block has
    a negative eigenvalue or a step's blocks do not determine G_k; None when
    the solver has no Hessian function to ask (the caller assumes nothing).

    At step k the polish's KKT conditions give G_k L_on = 0 for its columns
    that are on, so G_k >= 0 iff G_k >= 0 on any subspace E that spans R^d
    together with them; an off column j gives E = span(e_j .. e_{d-1})."""
    if nlp.formulation != "cholesky" or "sensing_offset" not in nlp.info:
        return None
    found = _off_blocks(nlp, solver, p, z, lam_g)
    if found is None:
        return None
    steps, off_cols, blocks, spans = found
    if steps.size == 0:
        return True
    if not spans.all():
        return False
    for j in range(nlp.info["d"]):
        ent = _entries(nlp, j)
        at = off_cols[steps, j]
        if at.any() and np.linalg.eigvalsh(blocks[at][:, ent][:, :, ent])[:, 0].min() < 0.0:
            return False
    return True


def descent_columns(nlp: NLPProblem, solver: Any, p: np.ndarray, z: np.ndarray,
                    lam_g: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray, float]]:
    """(step, positions in z, direction, eigenvalue) of every step whose first
    switched-off column j has a negative block: sensing S_k + t v v^T with v
    that block's eigenvector of its smallest eigenvalue (entries j..d-1 of
    column j) lowers the Lagrangian at ``z`` (module doc). Empty for another
    formulation or a solver without a Hessian function; a step whose blocks do
    not determine G_k is left out."""
    if nlp.formulation != "cholesky" or "sensing_offset" not in nlp.info:
        return []
    found = _off_blocks(nlp, solver, p, z, lam_g)
    if found is None:
        return []
    steps, off_cols, blocks, spans = found
    t, off, out = len(nlp.info["tri"]), nlp.info["sensing_offset"], []
    for a, k in enumerate(steps):
        ent = _entries(nlp, int(off_cols[k].argmax()))
        w, V = np.linalg.eigh(blocks[a][np.ix_(ent, ent)])
        if spans[a] and w[0] < 0.0:
            out.append((int(k), off + int(k) * t + ent, V[:, 0], float(w[0])))
    return out
