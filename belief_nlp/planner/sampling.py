"""Random beliefs (x, P) for IG-RRT*: uniform means, random covariances."""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = ["BeliefSampler", "SampleStream"]

_BLOCK = 256    # samples drawn per block by :class:`SampleStream`


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

    def stream(self, rng: np.random.Generator) -> "SampleStream":
        """The samples :meth:`draw` gives on ``rng``, in the same order and bit
        for bit, drawn in blocks (see :class:`SampleStream`). The stream
        draws ahead: use ``rng`` for nothing else while it is in use."""
        return SampleStream(self, rng)

    def _rotation(self, rng: np.random.Generator) -> np.ndarray:
        d = self.dim
        if d == 2:
            t = math.pi * rng.random()
            c, s = math.cos(t), math.sin(t)
            return np.array([[c, -s], [s, c]])
        # Haar-random orthogonal matrix: QR of a Gaussian matrix with the sign fix.
        Q, Rm = np.linalg.qr(rng.standard_normal((d, d)))
        return Q * np.sign(np.diag(Rm))


class SampleStream:
    """The samples of :meth:`BeliefSampler.draw` on one Generator, in blocks.

    A planner attempt is a few hundred microseconds, and a scalar draw (six
    Generator calls and a few small arrays) was a tenth of it. In 2-D every
    random number of a draw is one ``rng.random()`` double (``uniform(-1, 1)``
    is ``-1 + 2 u`` of the same double, a rotation angle ``pi u``), so a
    block of doubles from one ``rng.random(k)`` call, consumed in the scalar
    order, gives the same numbers; the covariances of a block are then one
    stacked product (numpy multiplies a stack matrix by matrix, the same
    products as one at a time). Other dimensions draw one sample per call.
    """

    def __init__(self, sampler: BeliefSampler, rng: np.random.Generator):
        self.sampler, self.rng = sampler, rng
        # the doubles of rng.random(8 * _BLOCK) calls, one after the other, drawn on demand
        self._uniform = itertools.chain.from_iterable(iter(lambda: rng.random(8 * _BLOCK).tolist(), None)).__next__
        self._x = self._P = None
        self._i = self._n = 0

    def _refill(self) -> None:
        sp = self.sampler
        nxt = self._uniform
        # (lo0, lo1, w0, w1, poly, is_box) of the domain and the target, as Python floats
        boxes = {name: (*lo.tolist(), *(hi - lo).tolist(), poly, is_box)
                 for name, (poly, lo, hi, is_box) in sp._boxes.items()}
        xs, lams, rots = [], [], []
        for i in range(_BLOCK):
            goal = sp.goal_bias > 0 and nxt() < sp.goal_bias
            lo0, lo1, w0, w1, poly, is_box = boxes["target" if goal else "domain"]
            for _ in range(10000):
                x = [lo0 + w0 * nxt(), lo1 + w1 * nxt()]
                if is_box or np.all(poly.A @ np.array(x) <= poly.b):
                    break
            else:  # pragma: no cover
                raise RuntimeError("could not sample inside a polytope (degenerate?)")
            lam0 = math.exp(sp.log_lo + (sp.log_hi - sp.log_lo) * nxt())
            u = -1.0 + 2.0 * nxt()
            t = math.pi * nxt()
            c, s = math.cos(t), math.sin(t)
            xs += x
            lams += (lam0, min(max(lam0 * math.exp(sp.log_ratio * u), sp.lo), sp.hi))
            rots += (c, -s, s, c)
        xs = np.array(xs).reshape(_BLOCK, 2)
        lam = np.array(lams).reshape(_BLOCK, 1, 2)
        R = np.array(rots).reshape(_BLOCK, 2, 2)
        P = (R * lam) @ np.swapaxes(R, 1, 2)
        self._x, self._P = xs, 0.5 * (P + np.swapaxes(P, 1, 2))
        # (L^-1_11, L^-1_21, L^-1_22) of each P, the operations of
        # :func:`.kernels.chol_factors` elementwise (the same values)
        a, b, c = self._P[:, 0, 0], 0.5 * (self._P[:, 0, 1] + self._P[:, 1, 0]), self._P[:, 1, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            l11 = np.sqrt(a)
            l21 = b / l11
            r = c - l21 * l21
            l22 = np.sqrt(r)
            lin = np.stack([1.0 / l11, -l21 / (l11 * l22), 1.0 / l22], axis=1).tolist()
        ok = ((a > 0) & (r > 0)).tolist()
        self._lin = [v if k else None for v, k in zip(lin, ok)]
        self._i, self._n = 0, _BLOCK

    def next(self) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float] | None]:
        """The next sample (x, P), as :meth:`BeliefSampler.draw` would give it,
        and in 2-D the entries (L^-1_11, L^-1_21, L^-1_22) of its Cholesky
        factor's inverse as :func:`.kernels.chol_factors` computes them (None
        in other dimensions, or when P is not positive definite)."""
        if self.sampler.dim != 2:
            return (*self.sampler.draw(self.rng), None)
        if self._i == self._n:
            self._refill()
        i = self._i
        self._i += 1
        return self._x[i], self._P[i], self._lin[i]
