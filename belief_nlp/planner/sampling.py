"""Random beliefs (x, P) for IG-RRT*: uniform means, random covariances."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["BeliefSampler"]


class BeliefSampler:
    """Draws the raw samples of IG-RRT*, before steering and shrinking.

    * x: uniform in the domain (rejection from its bounding box), or with
      probability ``goal_bias`` uniform in the target.
    * P = R diag(lam) R^T: lam_1 log-uniform in ``eig_range``, the other
      eigenvalues lam_1 * eig_ratio^u with u uniform in [-1, 1] (clipped to
      the range), R a uniformly random rotation. The authors draw
      P11 = 1e-9 + U * 10^-k (k = 1..8) and P22 = P11 * 10^U(-1, 1), a
      near-isotropic, log-spread law that this reproduces in any dimension.

    All randomness comes from the Generator passed in, in a fixed order, so a
    run is reproducible from its seed.
    """

    def __init__(self, scenario, eig_range: tuple[float, float], eig_ratio: float, goal_bias: float):
        self.dim = scenario.dim
        self.domain = scenario.domain
        self.target = scenario.target
        self.log_lo, self.log_hi = math.log(eig_range[0]), math.log(eig_range[1])
        self.lo, self.hi = eig_range
        self.log_ratio = math.log(eig_ratio)
        self.goal_bias = goal_bias
        self._boxes = {name: (poly, *self._box(poly)) for name, poly in (("domain", self.domain),
                                                                        ("target", self.target))}

    @staticmethod
    def _box(poly) -> tuple[np.ndarray, np.ndarray, bool]:
        """Bounding box of a polytope and whether the polytope is that box."""
        lo, hi = poly.vertices.min(axis=0), poly.vertices.max(axis=0)
        corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(lo.size, -1).T
        is_box = bool(np.all(corners @ poly.A.T <= poly.b + 1e-12 * (1 + np.abs(poly.b))))
        return lo, hi, is_box

    def _uniform_in(self, which: str, rng: np.random.Generator) -> np.ndarray:
        poly, lo, hi, is_box = self._boxes[which]
        for _ in range(10000):
            x = lo + (hi - lo) * rng.random(lo.size)
            if is_box or np.all(poly.A @ x <= poly.b):
                return x
        raise RuntimeError("could not sample inside a polytope (degenerate?)")  # pragma: no cover

    def draw(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One raw sample (x, P)."""
        goal = self.goal_bias > 0 and rng.random() < self.goal_bias
        x = self._uniform_in("target" if goal else "domain", rng)
        d = self.dim
        lam0 = math.exp(self.log_lo + (self.log_hi - self.log_lo) * rng.random())
        if d == 2:      # the general branch in Python floats (the same values, fewer numpy calls)
            u = rng.uniform(-1.0, 1.0, 1)[0]
            lam = np.array([lam0, min(max(lam0 * math.exp(self.log_ratio * u), self.lo), self.hi)])
        else:
            lam = np.empty(d)
            lam[0] = lam0
            if d > 1:
                lam[1:] = np.clip(lam0 * np.exp(self.log_ratio * rng.uniform(-1.0, 1.0, d - 1)), self.lo, self.hi)
        R = self._rotation(rng)
        P = (R * lam) @ R.T
        return x, 0.5 * (P + P.T)

    def _rotation(self, rng: np.random.Generator) -> np.ndarray:
        d = self.dim
        if d == 2:
            t = math.pi * rng.random()
            c, s = math.cos(t), math.sin(t)
            return np.array([[c, -s], [s, c]])
        # Haar-random orthogonal matrix: QR of a Gaussian matrix with the sign fix.
        Q, Rm = np.linalg.qr(rng.standard_normal((d, d)))
        return Q * np.sign(np.diag(Rm))
