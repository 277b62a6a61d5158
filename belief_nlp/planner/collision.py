"""Exact collision decisions for the planner (obstacles and domain walls).

Every decision is exact for the continuous transition x(s) = x_prev +
s (x_next - x_prev), P(s) = P_prev + s W_e, s in [0, 1] (paper Definition 3):
no edge is ever accepted because a few sampled ellipses were clear. Cheap
layers decide what they can, each a rigorous certificate or witness; what
they leave open goes, in one batched call, to
:func:`belief_nlp.geometry.transition_bounds` (paper Theorem 1 as a 1-D
convex minimisation over s), which accepts on its lower bound only.

1. **Screen** (:class:`.screen.HazardScreen`), every (edge, hazard) pair of a
   batch in a few numpy calls: face certificates with P(1), the largest
   covariance of the sweep; the mean segment meeting the hazard; in 2-D the
   end ellipse overlapping it. With ``ordered`` parent candidates the edges
   after the first one the screen proves clear are not decided further.
2. **Walls** (half-spaces {a^T y <= b}, the outside of the domain) left open,
   exactly in closed form: the transition is clear iff g(s) = (a^T x(s) - b)
   - sqrt(chi2' a^T P(s) a) >= 0 on [0, 1]; g is linear minus the root of a
   linear function, hence convex, with a closed-form minimiser.
3. **Obstacles** left open, per pair and sub-interval [s_a, s_b] of [0, 1]
   (halved up to ``_DEPTH`` times while undecided, in 2-D ``_DEPTH2`` or
   ``_SCALAR_DEPTH`` times, :meth:`CollisionChecker._refine`):

   - *certificates of clearance*. P(s) <= P(s_b) on the interval, so every
     ellipse there lies inside E(x(s), P(s_b)). In 2-D: the sub-segment
     whitened by P(s_b) stays at distance >= sqrt(chi2') from the whitened
     polygon (and does not cross it), so the swept ellipse misses the
     obstacle. In 3-D: some face a^T y <= b has min(a^T x(s_a), a^T x(s_b))
     - b >= sqrt(chi2' a^T P(s_b) a), so they all lie beyond that face
     (support function; paper Remark 1 with errata 2).
   - *witnesses of collision*: the ellipse at the middle of the interval
     (3-D: also at its end) overlaps the obstacle (2-D: exact Mahalanobis
     distance to the polygon in whitened coordinates; 3-D: a vertex inside
     the ellipse). One colliding s proves the transition unsafe.
4. **Exact**: the edges with pairs still open.

chi2' = chi2 (1 + safety_margin) in every layer, including the exact call;
witnesses use chi2' (1 - 1e-9) so that rounding cannot fake one. The exact
call accepts a pair only on its rigorous lower bound
(:func:`belief_nlp.geometry.transition_bounds`); a pair whose bounds do not
decide it (iteration limit, or a minimum within rounding of chi2') counts as
a collision and in ``stats["undecided_pairs"]``. tests/test_planner_fast_paths.py
holds every layer to the exact minimum on random and grazing edges.
"""

from __future__ import annotations

import math

import numpy as np

from .. import geometry
from .kernels import _ZERO, _all, _any, _min
from .refine_scalar import refine_pairs
from .screen import HazardScreen

__all__ = ["CollisionChecker"]

_DEPTH = 4          # sub-interval halvings before handing a pair to the exact minimiser (3-D; 4: fastest, measured)
# 2-D (measured on the recorded batches of two paper-multi runs, all with the
# same verdicts): with the Python-float layers for small batches a
# sub-interval costs about 1 % of an exact call, so both go deeper before
# the exact minimiser (exact calls per two runs 124 -> 9, replay 2.10 -> 1.89 s)
_DEPTH2 = 8         # halvings of the numpy layers
_SCALAR_PAIRS = 64  # open pairs up to which the layers run in Python floats (24-10000: the same time here)
_SCALAR_DEPTH = 10  # halvings of the Python-float layers


def _chol2(P: np.ndarray):
    """Entries of the lower Cholesky factor of 2x2 SPD matrices (R, 2, 2)."""
    l11 = np.sqrt(P[:, 0, 0])
    l21 = P[:, 0, 1] / l11
    l22 = np.sqrt(np.maximum(P[:, 1, 1] - l21 * l21, 0.0))
    return l11[:, None], l21[:, None], l22[:, None]


def _whiten(rel: np.ndarray, l11, l21, l22):
    """w = L^-1 rel for rel (R, k, 2), one factor per row."""
    w0 = rel[..., 0] / l11
    return w0, (rel[..., 1] - l21 * w0) / l22


def _boundary_dist2(x, P, V, E) -> np.ndarray:
    """Squared Mahalanobis distance under P (R, 2, 2) from x (R, 2) to the
    boundary of the convex polygon of each row, vertices V (R, k, 2) and edge
    vectors E (R, k, 2) (zero edges pad). For x outside the polygon it is
    the distance to the polygon. Whitening is linear, so the whitened
    polygon's edges are the whitened edge vectors."""
    return _boundary_parts(x, P, V, E)[0]


def _boundary_parts(x, P, V, E):
    """:func:`_boundary_dist2`, and the factor entries and whitened vertices
    (relative to x) it computed on the way."""
    L = _chol2(P)
    w0, w1 = _whiten(V - x[:, None, :], *L)
    e0, e1 = _whiten(E, *L)
    ee = e0 * e0 + e1 * e1 + 1e-300
    t = np.minimum(np.maximum(-(w0 * e0 + w1 * e1) / ee, 0.0), 1.0)
    q0 = w0 + t * e0
    q1 = w1 + t * e1
    return _min(q0 * q0 + q1 * q1, axis=1), L, w0, w1


def _sweep_dist2(xa, xb, Pb, xm, Pm, V, E) -> tuple[np.ndarray, np.ndarray]:
    """(segment, middle) for rows of sub-intervals: the squared Mahalanobis
    distance under Pb from each row's polygon (V, E as in
    :func:`_boundary_dist2`) to the segment [xa, xb], which must not meet
    it, and under Pm to the point xm. The segment's is attained at one of
    its ends or at a vertex of the polygon (disjoint convex sets in the
    plane); the three point distances take one call, whose first rows (xa
    under Pb) also give the factor and whitened polygon of the segment's."""
    R = xa.shape[0]
    d, L3, v0, v1 = _boundary_parts(np.concatenate([xa, xb, xm]), np.concatenate([Pb, Pb, Pm]),
                                    np.concatenate([V, V, V]), np.concatenate([E, E, E]))
    L = tuple(c[:R] for c in L3)
    w0, w1 = v0[:R], v1[:R]                                          # polygon, origin at xa
    u0, u1 = _whiten((xb - xa)[:, None, :], *L)                      # segment is {t u, t in [0, 1]}
    t = np.minimum(np.maximum((w0 * u0 + w1 * u1) / (u0 * u0 + u1 * u1 + 1e-300), 0.0), 1.0)
    r0, r1 = w0 - t * u0, w1 - t * u1
    seg = np.minimum(np.minimum(d[:R], d[R:2 * R]), _min(r0 * r0 + r1 * r1, axis=1))
    return seg, d[2 * R:]


class CollisionChecker:
    """Clearance decisions against ``scenario.hazards`` (obstacles and walls).

    The collisions are decided at ``chi2`` (default ``scenario.chi2``), the
    target containment always at ``scenario.chi2``: a risk budget raises the
    collision level only (:mod:`.budget`); the target is no collision."""

    exact_max_iter = 60     # rounds of the exact minimiser before a pair is left undecided

    def __init__(self, scenario, safety_margin: float, chi2: float | None = None):
        self.dim = scenario.dim
        self.chi2 = float(scenario.chi2 if chi2 is None else chi2)
        self.thr = self.chi2 * (1.0 + safety_margin)
        self.thr_target = float(scenario.chi2) * (1.0 + safety_margin)
        self.thr_witness = self.thr * (1.0 - 1e-9)
        self._thr0 = np.array(self.thr)             # (0-d: see kernels._const)
        walls = [h for h in scenario.hazards if h.A.shape[0] == 1]
        obstacles = [h for h in scenario.hazards if h.A.shape[0] > 1]
        self.wall_a = np.array([w.A[0] for w in walls]).reshape(-1, self.dim)
        self.wall_b = np.array([w.b[0] for w in walls])
        self.n_obs = len(obstacles)
        if obstacles:
            self.ps = geometry.PolytopeSet.build(obstacles)
            self.A = self.ps.A                                        # (m, F, d), inert padding 0 <= 1
            self.b = self.ps.b
            self.valid_face = np.arange(self.A.shape[1])[None, :] < self.ps.n_faces[:, None]
            k = max(o.vertices.shape[0] for o in obstacles)
            self.V = np.stack([np.concatenate([o.vertices, np.repeat(o.vertices[-1:], k - o.vertices.shape[0], 0)])
                               for o in obstacles])                   # (m, k, d), padded by repeating
            # 2-D: edge vectors of the CCW polygons (the padding gives zero edges)
            self.E = np.roll(self.V, -1, axis=1) - self.V
            if self.dim == 2:
                for i, o in enumerate(obstacles):
                    kk = o.vertices.shape[0]
                    self.E[i, kk - 1] = o.vertices[0] - o.vertices[-1]
                    self.E[i, kk:] = 0.0
                # the polygons as Python floats for the scalar sub-interval layers
                self._polys = [list(zip(*self.V[i].T.tolist(), *self.E[i].T.tolist())) for i in range(len(obstacles))]
        # obstacles first, so that screen column j < n_obs is obstacle j
        self.screen = HazardScreen(obstacles + walls, self.thr, self.thr_witness) if obstacles + walls else None
        target = scenario.target
        self.tA, self.tb = target.A, target.b
        # edges: checked; screened: decided (or skipped) by the screen alone;
        # refined: by the sub-interval layers; exact: by the exact minimiser
        self.stats = {"edges": 0, "edges_screened": 0, "edges_skipped": 0, "edges_refined": 0, "edges_exact": 0,
                      "exact_calls": 0, "pairs_exact": 0, "undecided_pairs": 0, "ellipses": 0, "ellipses_exact": 0}

    # ------------------------------------------------------------------ walls
    def _walls_clear(self, x0, x1, P0, W_e) -> np.ndarray:
        if self.wall_a.shape[0] == 0:
            return np.ones(x0.shape[0], dtype=bool)
        a = self.wall_a
        l0 = x0 @ a.T - self.wall_b                                  # (n, L): a^T x(0) - b
        dl = (x1 - x0) @ a.T
        q0 = self.thr * np.einsum("li,nij,lj->nl", a, P0, a)
        qw = self.thr * np.einsum("li,nij,lj->nl", a, W_e, a)
        with np.errstate(divide="ignore", invalid="ignore"):
            # stationary point of g(s) = l0 + s dl - sqrt(q0 + s qw): sqrt(q) = qw / (2 dl)
            s_star = ((qw / (2.0 * dl)) ** 2 - q0) / qw
        s_star = np.where((dl > 0) & (qw > 0) & np.isfinite(s_star), np.clip(s_star, 0.0, 1.0), 0.0)

        def g(s):
            return l0 + s * dl - np.sqrt(np.maximum(q0 + s * qw, 0.0))

        gmin = np.minimum(np.minimum(g(0.0), g(1.0)), g(s_star))
        return (gmin >= 0.0).all(axis=1)

    # -------------------------------------------------- obstacles, row-wise
    def _ellipse_hits(self, x, P, j) -> np.ndarray:
        """(R,) a proof that E(x, P) (chi2') overlaps obstacle j, for means x
        known to be outside it."""
        if self.dim == 2:
            return _boundary_dist2(x, P, self.V[j], self.E[j]) < self.thr_witness
        rel = self.V[j] - x[:, None, :]                              # (R, k, d)
        sol = np.linalg.solve(P, np.swapaxes(rel, -1, -2))           # (R, d, k)
        return (np.einsum("rkd,rdk->rk", rel, sol) < self.thr_witness).any(axis=1)

    def _face_certificates(self, j, xa, xb, Pb) -> np.ndarray:
        """(R,) a face of obstacle j with every ellipse of the sub-interval
        beyond it: min(a^T xa, a^T xb) - b >= sqrt(chi2' a^T Pb a) > 0, Pb the
        largest covariance of the sub-interval (padded faces 0 <= 1 never pass)."""
        A, b = self.A[j], self.b[j]
        slack = np.minimum(np.einsum("rfd,rd->rf", A, xa), np.einsum("rfd,rd->rf", A, xb)) - b
        aPa = np.einsum("rfd,rde,rfe->rf", A, Pb, A)
        return _any((slack > 0) & (slack * slack >= self.thr * aPa), axis=1)

    def _refine(self, x0, x1, P0, W_e, e, j) -> np.ndarray:
        """Decide the open (edge e, obstacle j) pairs; returns the blocked edges, (n,).

        Each pair carries a sub-interval [sa, sb] of [0, 1] (first the whole
        transition), with the means xa, xb at its ends and Pb = P(sb), the
        largest covariance on it. Per round, on the pairs still open: in 2-D
        the certificate that the sub-segment whitened by Pb stays sqrt(chi2')
        away from the polygon; in 3-D the face certificates (from the second
        round on: on [0, 1] the screen did them) and the witness at s = 1 (in
        2-D the screen did it); then the witness at the middle sm. An open pair is
        split into [sa, sm] and [sm, sb], up to ``_DEPTH`` times; the edges
        still open then go to the exact check. No other test needs repeating
        on a sub-interval: the whole mean segment misses the obstacle (the
        screen), and every end of a sub-interval was the middle or an end of
        an earlier one, so its ellipse was tested already.
        """
        if self.dim == 2:
            return self._refine2(x0, x1, P0, W_e, e, j)
        n = x0.shape[0]
        dx = x1 - x0
        sa = np.zeros(e.size)
        sb = np.ones(e.size)
        xa = x0[e]
        xb = x0[e] + dx[e]
        Pb = P0[e] + W_e[e]
        blocked = np.zeros(n, dtype=bool)
        for depth in range(_DEPTH + 1):
            clear = self._face_certificates(j, xa, xb, Pb) if depth else np.zeros(e.size, dtype=bool)
            hit = np.zeros(e.size, dtype=bool)
            r = (~clear).nonzero()[0]
            if r.size and depth == 0:
                hit[r] = self._ellipse_hits(xb[r], Pb[r], j[r])
                r = r[~hit[r]]
            if r.size:
                sm = 0.5 * (sa[r] + sb[r])
                er = e[r]
                xm = x0[er] + sm[:, None] * dx[er]
                Pm = P0[er] + sm[:, None, None] * W_e[er]
                hit[r] = self._ellipse_hits(xm, Pm, j[r])
            blocked[e[hit]] = True
            if depth == _DEPTH or not r.size:
                e = e[r[~hit[r] & ~clear[r]]]
                break
            keep = ~hit[r] & ~clear[r] & ~blocked[e[r]]
            r, sm, xm, Pm = r[keep], sm[keep], xm[keep], Pm[keep]
            e = np.concatenate([e[r], e[r]])
            j = np.concatenate([j[r], j[r]])
            sa, sb = np.concatenate([sa[r], sm]), np.concatenate([sm, sb[r]])
            xa, xb = np.concatenate([xa[r], xm]), np.concatenate([xm, xb[r]])
            Pb = np.concatenate([Pm, Pb[r]])
            if not e.size:
                break
        return self._exact_rest(x0, x1, P0, W_e, e, blocked)

    def _refine2(self, x0, x1, P0, W_e, e, j) -> np.ndarray:
        """:meth:`_refine` in 2-D: every row at once (fewer calls than
        compressing first): the sweep certificate (it implies the face
        certificates: a capsule beyond a face misses the polygon), then the
        middle witness where it fails. The data of each pair (its edge's
        start, step, covariance, noise, and its polygon) is gathered once and
        carried along the splits. Up to ``_SCALAR_PAIRS`` pairs, the same
        layers in Python floats (:func:`.refine_scalar.refine_pairs`: the same
        verdicts, a tenth of the time on a few pairs)."""
        blocked = np.zeros(x0.shape[0], dtype=bool)
        xs = x0.take(e, axis=0)
        dx = x1.take(e, axis=0) - xs
        Ps, We = P0.take(e, axis=0), W_e.take(e, axis=0)
        if e.size <= _SCALAR_PAIRS:
            n = e.size
            res = refine_pairs(zip(e.tolist(), j.tolist(), xs.tolist(), dx.tolist(), Ps.reshape(n, 4).tolist(),
                                   We.reshape(n, 4).tolist()), self._polys, self.thr, self.thr_witness, _SCALAR_DEPTH)
            if res is not None:
                hit, left = res
                blocked[list(hit)] = True
                return self._exact_rest(x0, x1, P0, W_e, np.array(sorted(left), dtype=np.intp), blocked)
        V, E = self.V.take(j, axis=0), self.E.take(j, axis=0)
        sa = np.zeros(e.size)
        sb = np.ones(e.size)
        xa, xb, Pb = xs, xs + dx, Ps + We
        for depth in range(_DEPTH2 + 1):
            sm = 0.5 * (sa + sb)
            xm = xs + sm[:, None] * dx
            Pm = Ps + sm[:, None, None] * We
            seg, mid = _sweep_dist2(xa, xb, Pb, xm, Pm, V, E)
            clear = seg >= self.thr
            hit = (mid < self.thr_witness) & ~clear
            blocked[e[hit]] = True
            if depth == _DEPTH2:
                e = e[~hit & ~clear]
                break
            r = (~(hit | clear | blocked[e])).nonzero()[0]
            if not r.size:
                e = e[r]
                break
            # (take: numpy's fancy indexing of a leading axis is several times slower)
            rr = np.concatenate([r, r])
            e, sa, sb = e[rr], np.concatenate([sa[r], sm[r]]), np.concatenate([sm[r], sb[r]])
            xs, dx, Ps, We, V, E = (a.take(rr, axis=0) for a in (xs, dx, Ps, We, V, E))
            xa, xb = np.concatenate([xa.take(r, axis=0), xm.take(r, axis=0)]), np.concatenate([xm.take(r, axis=0),
                                                                                            xb.take(r, axis=0)])
            Pb = np.concatenate([Pm.take(r, axis=0), Pb.take(r, axis=0)])
        return self._exact_rest(x0, x1, P0, W_e, e, blocked)

    def _exact_rest(self, x0, x1, P0, W_e, e, blocked) -> np.ndarray:
        """The exact check of the edges ``e`` that the refinement left open
        (and did not block); updates and returns ``blocked``."""
        n = x0.shape[0]
        undecided = np.zeros(n, dtype=bool)
        undecided[e] = True
        undecided &= ~blocked
        rest = undecided.nonzero()[0]
        if rest.size:
            st = self.stats
            st["exact_calls"] += 1
            st["edges_exact"] += rest.size
            st["pairs_exact"] += rest.size * self.n_obs
            lower, upper = geometry.transition_bounds(x0[rest], P0[rest], x1[rest], W_e[rest], self.ps, self.thr,
                                                      max_iter=self.exact_max_iter)
            ok = lower >= self.thr                                    # proven clear
            st["undecided_pairs"] += int(np.count_nonzero(~ok & (upper >= self.thr)))
            blocked[rest] = ~ok.all(axis=1)
        return blocked

    def transitions_clear(self, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, W_e: np.ndarray,
                          ordered: int = 0) -> np.ndarray:
        """(n,) exact decision: is each transition (x0, P0) -> x1 with noise W_e (n, d, d) clear?

        With ``ordered = k``, the first k transitions are alternatives in order of
        preference of which only the first clear one matters (the planner's
        parent candidates): the ones after the first transition the screen
        proves clear are not decided, and come back False
        (``stats["edges_skipped"]``). All others are decided in full.
        """
        n = x0.shape[0]
        st = self.stats
        st["edges"] += n
        if self.screen is None:
            return np.ones(n, dtype=bool)
        P1 = P0 + W_e
        clear, seg = self.screen.clearances(x0, x1, P1)
        pending = ~clear                                # open (edge, hazard) pairs
        open_ = _any(pending, axis=1)
        skip = ordered
        if ordered:
            # the first parent candidate certified against every hazard ends
            # the search (a certified pair's segment meets no hazard)
            first = int(open_[:ordered].argmin())
            if not open_[first]:
                skip = first + 1
                open_[skip:ordered] = False
                st["edges_skipped"] += ordered - skip
        rows = open_.nonzero()[0]
        blocked = np.zeros(n, dtype=bool)
        if rows.size:
            # witnesses: the mean segment meets a hazard of an open pair
            hit = _any(self.screen.segment_hits(seg, rows) & pending.take(rows, axis=0), axis=1)
            if _any(hit):
                blocked[rows[hit]] = True
                rows = rows[~hit]
        st["edges_screened"] += n - rows.size
        if rows.size:
            self._decide_open(x0, x1, P0, W_e, P1, rows, pending, blocked)
        out = ~blocked
        out[skip:ordered] = False
        return out

    def _decide_open(self, x0, x1, P0, W_e, P1, rows, pending, blocked) -> None:
        """Decide the edges ``rows`` the certificates left open (their ``pending``
        pairs): the end witness, the walls in closed form, then the obstacles
        (:meth:`_refine`). Sets ``blocked`` in place."""
        m = self.n_obs
        wit = self.screen.end_witness(x1.take(rows, axis=0), P1.take(rows, axis=0))
        if wit is not None:
            more = _any(wit & pending.take(rows, axis=0), axis=1)
            if _any(more):
                blocked[rows[more]] = True
                rows = rows[~more]
        if rows.size and m < pending.shape[1]:
            wr = rows[_any(pending.take(rows, axis=0)[:, m:], axis=1)]
            if wr.size:
                # the walls exactly, in closed form
                ok = self._walls_clear(x0[wr], x1[wr], P0[wr], W_e[wr])
                if not ok.all():
                    blocked[wr[~ok]] = True
                    rows = rows[~blocked[rows]]
        if rows.size and m:
            sub = pending.take(rows, axis=0)[:, :m]
            e, j = sub.nonzero()
            if e.size:
                st = self.stats
                st["edges_refined"] += rows.size
                blocked |= self._refine(x0, x1, P0, W_e, rows[e], j)

    # ---------------------------------------------------------------- samples
    def shrink_exponent(self, x: np.ndarray, P: np.ndarray) -> int | None:
        """Smallest k >= 0 such that E(x, P / 2^k) is clear of every hazard, or
        None when the mean itself is inside a hazard (or on its boundary).

        The squared Mahalanobis distance scales as 1/c when P is scaled by c,
        so the exact distances give k in closed form (the authors halve P and
        re-check until clear).
        """
        self.stats["ellipses"] += 1
        d2 = math.inf
        if self.screen is None:
            return 0
        inside, slack, aPa = self.screen.ellipse(x, P)
        if _any(inside):
            return None
        # a face of every hazard with the ellipse beyond it: clear as it is
        ok = _any((slack > _ZERO) & (slack * slack >= self._thr0 * np.maximum(aPa, _ZERO)), axis=0)
        if _all(ok):
            return 0
        m = self.n_obs
        if m < slack.shape[1]:
            # walls (one face each, after the obstacles): exact in closed form
            sw = slack[0, m:]
            d2 = float(_min(sw * sw / aPa[0, m:]))
        if m:
            if not _all(ok[:m]):
                self.stats["ellipses_exact"] += 1
                if self.dim == 2:
                    # the mean is outside every obstacle (checked above)
                    m = self.n_obs
                    d2o = float(np.min(_boundary_dist2(np.broadcast_to(x, (m, 2)), np.broadcast_to(P, (m, 2, 2)),
                                                       self.V, self.E)))
                else:
                    d2o = float(np.min(geometry.ellipse_clearances(x[None], P[None], self.ps, self.chi2)) + self.chi2)
                if not d2o > 0:
                    return None
                d2 = min(d2, d2o)
        if d2 >= self.thr:
            return 0
        return int(math.ceil(math.log2(self.thr / d2) + 1e-12))

    # ----------------------------------------------------------------- target
    def in_target(self, x: np.ndarray, P: np.ndarray) -> bool:
        """Is E(x, P) inside the target (support function, chi2 with margin)?"""
        if _any(self.tb - x @ self.tA.T < _ZERO):   # the mean outside: no margin can be >= 0
            return False
        return bool(np.min(geometry.containment_margins(x, P, self.tA, self.tb, self.thr_target)) >= 0.0)
