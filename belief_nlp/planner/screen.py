"""All-pairs screening of a batch of transitions against every hazard, in a few numpy calls.

The planner's collision batches are small (a few to a few hundred edges
against about ten hazards), so their cost is the number of numpy calls, not
their size. This screen decides most (edge, hazard) pairs of a batch with
one matrix product and about thirty elementwise calls over the whole
(edges x faces) grid, with no gathers; :mod:`.collision` refines only the
pairs it leaves open. Every verdict is rigorous, for the transition
x(s) = x0 + s (x1 - x0), P(s) = P0 + s W_e, s in [0, 1] (paper Definition 3),
with P1 = P0 + W_e >= P(s) (W_e >= 0), so every ellipse of the sweep lies in
E(x(s), P1):

* **clear** (a certificate): a face {a^T y <= b} of the hazard has
  min(a^T x0, a^T x1) - b >= sqrt(chi2' a^T P1 a) > 0, so every ellipse of
  the sweep lies beyond it (support function, paper Remark 1 with errata 2);
* **hit** (a witness of collision): the mean segment meets the hazard
  (Liang-Barsky clipping against its faces), or, in 2-D, the end ellipse
  E(x1, P1) overlaps it (its exact Mahalanobis distance, the planar point
  kernel of :mod:`belief_nlp.geometry`, is below chi2' (1 - 1e-9), so
  rounding cannot fake a witness).

(Adding the faces of the obstacles' bounding boxes as further certificates
was measured: 1 % more pairs cleared on paper-multi, for twice the work per
batch; left out.)

A pair neither clear nor hit is open: the caller decides it exactly.
"""

from __future__ import annotations

import numpy as np

from ..geometry.planar import _planar_points, _small_k_matmul
from ..geometry.polytopes import _Planar
from .kernels import _INF, _NINF, _ONE, _ZERO, _all, _any, _max, _min

__all__ = ["HazardScreen"]


class HazardScreen:
    """Certificates and witnesses for every (transition, hazard) pair of a batch.

    Parameters
    ----------
    hazards : sequence of :class:`~belief_nlp.polytope.Polytope`
        The hazards, in the column order of the results.
    thr, thr_witness : float
        chi2' (a certificate must clear it) and chi2' (1 - 1e-9) (a witness
        must fall below it).
    """

    def __init__(self, hazards, thr: float, thr_witness: float):
        self.dim = d = hazards[0].A.shape[1]
        self.thr, self.thr_witness = thr, thr_witness
        faces = [list(zip(h.A, h.b)) for h in hazards]
        # Every hazard gets the same number of faces, padded with copies of its
        # first face (a copy changes no test), and the faces are stored face
        # by face across the hazards (row f H + h): the per-hazard reductions
        # are then reductions over the first axis of (Fm, H, n), which numpy
        # runs as a few contiguous elementwise passes (over a short last axis
        # it is several times slower).
        self.H, self.Fm = len(faces), max(len(f) for f in faces)
        rows = [f[i] if i < len(f) else f[0] for i in range(self.Fm) for f in faces]
        A = np.array([a for a, _ in rows])
        b = np.array([bb for _, bb in rows])
        G = A.shape[0]
        # One product of M with the data columns [1, x0, x1, vec(P1)] gives,
        # per face, [a^T x0 - b, a^T x1 - b, chi2' a^T P1 a] (vec(P1) uses all
        # d^2 entries, so P1 need not be exactly symmetric).
        quad = np.einsum("fi,fj->fij", A, A).reshape(G, d * d)
        Z = np.zeros((G, d))
        ZF = np.zeros((G, d * d))
        self.M = np.ascontiguousarray(np.block([[-b[:, None], A, Z, ZF],
                                                [-b[:, None], Z, A, ZF],
                                                [np.zeros((G, 1)), Z, Z, thr * quad]]))
        self.G = G
        self.A, self.b, self.quad = A, b, np.ascontiguousarray(quad.T)
        self.planar = _Planar.build([(h.A, h.b) for h in hazards]) if d == 2 else None
        self._ones = np.ones((256, 1))     # the data's first column, sliced (np.ones per call: 2.5 us)

    def certify(self, x0: np.ndarray, x1: np.ndarray, P1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(hit, clear), each (n, H): mean segments that meet a hazard, and the
        face certificates. ``x0``, ``x1`` (n, d) are the ends of the mean
        segments, ``P1`` (n, d, d) the covariance at s = 1 (the largest of the
        sweep). (:meth:`clearances`, then :meth:`segment_hits` of every edge.)"""
        clear, seg = self.clearances(x0, x1, P1)
        hit = self.segment_hits(seg, np.arange(x0.shape[0]))
        return hit, clear & ~hit

    def clearances(self, x0: np.ndarray, x1: np.ndarray, P1: np.ndarray) -> tuple[np.ndarray, tuple]:
        """The face certificates, (n, H), and the segments' face values for
        :meth:`segment_hits` (arguments as :meth:`certify`). A certified pair's
        segment misses the hazard (both ends are beyond one face), so only the
        edges that the certificates leave open need the witness, and the
        planner's parent search needs it only up to its first certified edge."""
        n, d = x0.shape[0], self.dim
        shape = (self.Fm, self.H, n)
        ones = self._ones
        if ones.shape[0] < n:
            ones = self._ones = np.ones((2 * n, 1))
        data = np.concatenate([ones[:n], x0, x1, P1.reshape(n, d * d)], axis=1)
        # (3 G, n) made contiguous in one copy, then split as (3, Fm, H, n)
        # views (slicing the transposed product and reshaping each third
        # copied three times)
        c0, c1, q = np.ascontiguousarray(_small_k_matmul(data, self.M.T).T).reshape((3,) + shape)
        slack = np.minimum(c0, c1)
        clear = _any((slack > _ZERO) & (slack * slack >= q), axis=0)
        return clear.T, (c0, c1)

    def segment_hits(self, seg: tuple, rows: np.ndarray) -> np.ndarray:
        """(len(rows), H): the mean segments of the edges ``rows`` (distinct,
        ascending) that meet a hazard (``seg`` from :meth:`clearances`)."""
        c0, c1 = seg
        if rows.size != c0.shape[2]:
            c0, c1 = c0.take(rows, axis=2), c1.take(rows, axis=2)
        # Liang-Barsky: the segment x0 + t (x1 - x0) is inside face f iff
        # t (c0 - c1) >= c0, so it meets the hazard iff max over the faces
        # with c0 > c1 of c0 / (c0 - c1) is at most the min over the others
        # (and [0, 1] meets that range). A face parallel to the segment
        # (c0 = c1) holds for no t when c0 > 0 (the segment runs outside it)
        # and for every t otherwise. (The division only where c0 != c1, into
        # the parallel faces' values: no floating-point warnings to silence.)
        den = c0 - c1
        ratio = np.divide(c0, den, out=np.where(c0 > _ZERO, _NINF, _INF), where=den != _ZERO)
        pos = den > _ZERO
        lower = _max(np.where(pos, ratio, _NINF), axis=0)
        upper = _min(np.where(pos, _INF, ratio), axis=0)
        return (np.maximum(lower, _ZERO) <= np.minimum(upper, _ONE)).T

    def ellipse(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For one ellipse E(x, P): (inside (H,): the mean is in the hazard or on
        its boundary; slack a^T x - b and aPa = a^T P a, each (Fm, H), face by
        face)."""
        slack = (self.A @ x - self.b).reshape(self.Fm, self.H)
        aPa = (P.reshape(-1) @ self.quad).reshape(self.Fm, self.H)
        return _all(slack <= _ZERO, axis=0), slack, aPa

    def end_witness(self, x1: np.ndarray, P1: np.ndarray) -> np.ndarray | None:
        """(n, H): the end ellipse E(x1, P1) overlaps the hazard (2-D; None in
        other dimensions, where :mod:`.collision` tests the end itself)."""
        if self.planar is None:
            return None
        return _planar_points(self.planar, x1, P1) < self.thr_witness
