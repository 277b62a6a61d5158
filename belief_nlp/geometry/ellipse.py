"""Confidence ellipses against polytopes: clearance (Lemma 1) and containment.

Clearance (paper Lemma 1): with G = A P A^T and c = b - A x, the squared
Mahalanobis distance from x to the polytope {y : A y <= b} is

    dist2 = min_{A y <= b} (y-x)^T P^-1 (y-x) = max_{lam >= 0} -lam^T G lam - 2 lam^T c

and the maximiser ``lam`` is the Lemma-1 certificate. The ellipse
E(x, P) = {y : (y-x)^T P^-1 (y-x) <= chi2} is clear of the polytope iff
dist2 >= chi2, so clearances are dist2 - chi2 (>= 0 means clear).

Containment of an ellipse in a polytope (domain, target) uses the support
function, b - a^T x - sqrt(chi2 a^T P a) per face (paper Remark 1 / Lemma 3
with errata 2-3).
"""

from __future__ import annotations

import numpy as np

from ._numeric import _batch, _quiet
from .generic import _evaluate, _prepare, _whitened
from .planar import _planar_points
from .polytopes import _as_set


@_quiet
def squared_mahalanobis_distance(x, P, polytopes) -> np.ndarray:
    """min over y in each polytope of (y-x)^T P^-1 (y-x); (n, m) for x (n, d)."""
    ps = _as_set(polytopes)
    xb, Pb, _ = _batch(x, P)
    if ps.planar is not None:
        return _planar_points(ps.planar, xb, np.broadcast_to(Pb, (xb.shape[0], 2, 2)))
    c, G, midx = _prepare(xb, Pb, ps)
    return _evaluate(c, G, midx, ps, B=_whitened(Pb, ps)).g.reshape(xb.shape[0], len(ps))


def ellipse_clearances(x, P, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`ellipse_clearance`: ellipses (n, d), (n, d, d) vs a
    :class:`PolytopeSet` (or list of polytopes) of m members -> (n, m)."""
    return squared_mahalanobis_distance(x, P, polytopes) - chi2


def ellipse_clearance(x, P, A, b, chi2: float):
    """Squared Mahalanobis distance under P from x to {y : A y <= b}, minus chi2.

    ``>= 0`` iff the confidence ellipse E(x, P) does not overlap the
    polytope (paper Lemma 1). ``x`` (d,) or (n, d), ``P`` (d, d) or (n, d, d);
    returns a float for a single ellipse, else an (n,) array. The value is
    ``-chi2`` when x lies inside the polytope.
    """
    xb, Pb, single = _batch(x, P)
    out = ellipse_clearances(xb, Pb, _as_set(A, b), chi2)[:, 0]
    return float(out[0]) if single else out


@_quiet
def ellipse_certificate(x, P, A, b) -> np.ndarray:
    """The Lemma-1 maximiser lam >= 0 (f,) of -lam^T A P A^T lam + 2 lam^T (A x - b).

    Its value equals the squared Mahalanobis distance, so the ellipse is clear
    iff the value is >= chi2. (Zero vector when x is inside the polytope.)
    """
    ps = _as_set(A, b)
    xb, Pb, _ = _batch(x, P)
    c, G, midx = _prepare(xb, Pb, ps)
    lam = _evaluate(c, G, midx, ps, want_lam=True, B=_whitened(Pb, ps)).lam[0, : ps.n_faces[0]]
    return np.maximum(lam, 0.0)


def containment_margins(x, P, A, b, chi2: float) -> np.ndarray:
    """Per face: b_i - a_i^T x - sqrt(chi2 a_i^T P a_i) (metres); (..., f).

    ``>= 0`` for every face iff E(x, P) lies inside {A y <= b}
    (paper Lemma 3 / eq. final_cond with the corrected signs, errata 2-4).
    """
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    aPa = np.einsum("fi,...ij,fj->...f", A, P, A)
    return b - x @ A.T - np.sqrt(chi2 * np.maximum(aPa, 0.0))


def containment_margin(x, P, A, b, chi2: float):
    """min over faces of :func:`containment_margins`: float for one ellipse."""
    out = np.min(containment_margins(x, P, A, b, chi2), axis=-1)
    return float(out) if np.ndim(out) == 0 else out
