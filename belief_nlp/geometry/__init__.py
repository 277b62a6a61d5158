"""Exact safety geometry of confidence ellipses against convex polytopes.

Notation: ellipse E(x, P) = {y : (y-x)^T P^-1 (y-x) <= chi2}; polytope
{y : A y <= b}. dist2 is the squared Mahalanobis distance under P from x to
the polytope (paper Lemma 1, whose maximiser ``lam`` is the certificate).
A transition x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W,
s in [0, 1] (paper Definition 3, Theorem 1 and errata 5) is clear iff the
minimum of dist2(s) over [0, 1] is >= chi2; that minimum is computed exactly
(a 1-D convex minimisation to ~1e-10, never sampling s). Margins are
"clearances": dist2 - chi2 (>= 0 means clear); containment margins use the
support function (paper Remark 1 / Lemma 3).

Modules:

* :mod:`.polytopes` -- :class:`PolytopeSet`, polytopes packed once for
  batched queries (face enumeration, 2-D edge and vertex lists);
* :mod:`.ellipse` -- Lemma 1: :func:`squared_mahalanobis_distance`,
  :func:`ellipse_clearance`, :func:`ellipse_clearances`,
  :func:`ellipse_certificate`, and :func:`containment_margin`,
  :func:`containment_margins`;
* :mod:`.transitions` -- Theorem 1: :class:`TransitionMinimum`,
  :func:`transition_minimiser`, :func:`transition_clearance`,
  :func:`transition_clearances`, :func:`transitions_clear`,
  :func:`transition_bounds`, :func:`transition_certificate`;
* :mod:`.bounds` -- the rigorous lower bound (Theorem-1 certificate value)
  every acceptance decides on;
* :mod:`.generic` -- the generic path (any dimension): Lemma 1 by face
  enumeration, bracketed minimisation over s;
* :mod:`.planar` -- the planar path (d = 2, the planner's common case):
  closed-form edges and vertex curves;
* :mod:`.minimise` -- the bracketed 1-D convex minimisation both paths share;
* :mod:`._numeric` -- small shared helpers (covariance floor, float-warning
  guard, batching).
"""

from __future__ import annotations

from .ellipse import (containment_margin, containment_margins, ellipse_certificate, ellipse_clearance,
                      ellipse_clearances, squared_mahalanobis_distance)
from .generic import _evaluate, _prepare  # noqa: F401 - the tests check the generic evaluation directly
from .minimise import TransitionMinimum
from .polytopes import PolytopeSet
from .transitions import (transition_bounds, transition_certificate, transition_clearance, transition_clearances,
                          transition_minimiser, transitions_clear)

__all__ = [
    "PolytopeSet",
    "squared_mahalanobis_distance",
    "ellipse_clearance",
    "ellipse_clearances",
    "transition_clearance",
    "transition_clearances",
    "transition_minimiser",
    "transitions_clear",
    "transition_bounds",
    "containment_margin",
    "containment_margins",
    "ellipse_certificate",
    "transition_certificate",
]
