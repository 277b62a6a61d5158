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

* **clear** (a certificate): some half-space {a^T y <= b} containing the
  hazard has min(a^T x0, a^T x1) - b >= sqrt(chi2' a^T P1 a) > 0, so every
  ellipse of the sweep lies beyond it (support function, paper Remark 1 with
  errata 2). The half-spaces are the hazard's faces and, for a bounded
  obstacle, the four (2-D) or six (3-D) faces of its bounding box, widened
  by 1e-9 of the scene's scale so that rounding in the vertices cannot make
  the box smaller than the obstacle;
* **hit** (a witness of collision): the mean segment meets the hazard
  (Liang-Barsky clipping against all of those half-spaces: the box faces
  contain the hazard, so they do not change the clip), or, in 2-D, the end
  ellipse E(x1, P1) overlaps it (its exact Mahalanobis distance, the
  planar point kernel of :mod:`belief_nlp.geometry`, is below chi2' (1 -
  1e-9), so rounding cannot fake a witness).

A pair neither clear nor hit is open: the caller decides it exactly.
"""

from __future__ import annotations

import numpy as np

from ..geometry.planar import _planar_points, _small_k_matmul
from ..geometry.polytopes import _Planar

__all__ = ["HazardScreen"]

_BOX_WIDEN = 1e-9   # relative widening of the obstacles' bounding boxes (vertices carry rounding)


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
        scale = 1.0 + max(float(np.max(np.abs(h.b))) for h in hazards)
        faces = []
        for h in hazards:
            rows = list(zip(h.A, h.b))
            if h.vertices is not None and h.A.shape[0] > 1:
                lo = h.vertices.min(axis=0) - _BOX_WIDEN * scale
                hi = h.vertices.max(axis=0) + _BOX_WIDEN * scale
                for k in range(d):
                    e = np.zeros(d)
                    e[k] = 1.0
                    rows.extend([(e, hi[k]), (-e, -lo[k])])
            faces.append(rows)
        # Every hazard gets the same number of faces, padded with copies of its
        # first face (a copy changes no test), so that per-hazard reductions are
        # plain reductions over the last axis of (n, H, Fm).
        self.H, self.Fm = len(faces), max(len(f) for f in faces)
        rows = [f[i] if i < len(f) else f[0] for f in faces for i in range(self.Fm)]
        A = np.array([a for a, _ in rows])
        b = np.array([bb for _, bb in rows])
        G = A.shape[0]
        # One product of the data rows [1, x0, x1, vec(P1)] with M gives, per
        # face, [a^T x0 - b, a^T x1 - b, a^T P1 a] (vec(P1) uses all d^2
        # entries, so P1 need not be exactly symmetric).
        quad = np.einsum("fi,fj->ijf", A, A).reshape(d * d, G)
        Z = np.zeros((d, G))
        ZF = np.zeros((d * d, G))
        self.M = np.ascontiguousarray(np.block([[-b[None], -b[None], np.zeros((1, G))],
                                                [A.T, Z, Z],
                                                [Z, A.T, Z],
                                                [ZF, ZF, quad]]))
        self.G = G
        self.A, self.b, self.quad = A, b, np.ascontiguousarray(quad)
        self.planar = _Planar.build([(h.A, h.b) for h in hazards]) if d == 2 else None

    def certify(self, x0: np.ndarray, x1: np.ndarray, P1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(hit, clear), each (n, H): mean segments that meet a hazard, and the
        face certificates. ``x0``, ``x1`` (n, d) are the ends of the mean
        segments, ``P1`` (n, d, d) the covariance at s = 1 (the largest of the
        sweep)."""
        n, d, G = x0.shape[0], self.dim, self.G
        shape = (n, self.H, self.Fm)
        data = np.concatenate([np.ones((n, 1)), x0, x1, P1.reshape(n, d * d)], axis=1)
        R = _small_k_matmul(data, self.M)
        c0, c1, aPa = (R[:, k * G:(k + 1) * G].reshape(shape) for k in range(3))
        slack = np.minimum(c0, c1)
        clear = ((slack > 0) & (slack * slack >= self.thr * aPa)).any(axis=2)
        # Liang-Barsky: the segment x0 + t (x1 - x0) is inside face f iff t * den <= num
        num = -c0
        den = c1 - c0
        lower = np.divide(num, den, out=np.full(shape, -np.inf), where=den < 0).max(axis=2)
        upper = np.divide(num, den, out=np.full(shape, np.inf), where=den > 0).min(axis=2)
        outside = ((den == 0) & (num < 0)).any(axis=2)
        hit = (np.maximum(lower, 0.0) <= np.minimum(upper, 1.0)) & ~outside
        return hit, clear & ~hit

    def ellipse(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For one ellipse E(x, P): (inside (H,): the mean is in the hazard or on
        its boundary; slack a^T x - b and aPa = a^T P a, each (H, Fm), face by
        face, the hazard's own faces first)."""
        slack = (self.A @ x - self.b).reshape(self.H, self.Fm)
        aPa = (P.reshape(-1) @ self.quad).reshape(self.H, self.Fm)
        # inside every face of the padded list <=> inside the hazard: the box
        # faces (widened) hold wherever the hazard's own faces do
        return (slack <= 0).all(axis=1), slack, aPa

    def end_witness(self, x1: np.ndarray, P1: np.ndarray) -> np.ndarray | None:
        """(n, H): the end ellipse E(x1, P1) overlaps the hazard (2-D; None in
        other dimensions, where :mod:`.collision` tests the end itself)."""
        if self.planar is None:
            return None
        return _planar_points(self.planar, x1, P1) < self.thr_witness
