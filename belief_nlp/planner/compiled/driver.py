"""The Python side of the compiled attempt: static data, buffers, the exact
fallback and the tree updates.

Per attempt: one compiled call (:func:`.attempt.attempt`) does steps 1-5 and
the collision decisions; Python then inserts the node and runs the rewiring
loop (a few rewires per hundred attempts), and, when the sub-interval layers
left an edge open (a few per run), decides it with the exact minimiser of
the numpy checker (:meth:`..collision.CollisionChecker._exact_rest`), then
the rewiring edges if the parent was among those.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..collision import _SCALAR_DEPTH
from ..iteration import _EIG_FLOOR_FACTOR, _REL_EPS
from .cache import drop_stale_cache

drop_stale_cache()          # before the compiled modules load their caches

from . import attempt as A  # noqa: E402
from .collide import CLEAR, EXACT, decide_batch  # noqa: E402

__all__ = ["CompiledAttempt", "hazard_arrays", "transitions_clear"]

# sub-interval halvings: those of the numpy checker's Python-float layers
_DEPTH = _SCALAR_DEPTH


def hazard_arrays(checker) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """(F, nf, n_obs, VE) of :mod:`.collide` from a 2-D checker: the faces of
    its screen (obstacles first, then walls; the screen pads each hazard with
    copies of its first face, which are dropped here) and its polygons."""
    scr = checker.screen
    if scr is None:
        return np.zeros((0, 1, 3)), np.zeros(0, dtype=np.int64), 0, np.zeros((0, 1, 4))
    H, Fm = scr.H, scr.Fm
    F = np.ascontiguousarray(np.concatenate([scr.A, scr.b[:, None]], axis=1).reshape(Fm, H, 3).transpose(1, 0, 2))
    nf = np.array([next((f for f in range(1, Fm) if np.array_equal(F[h, f], F[h, 0])), Fm) for h in range(H)],
                  dtype=np.int64)
    VE = (np.ascontiguousarray(np.concatenate([checker.V, checker.E], axis=2)) if checker.n_obs
          else np.zeros((0, 1, 4)))
    return F, nf, checker.n_obs, VE


def transitions_clear(checker, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, W_e: np.ndarray) -> np.ndarray:
    """(n,) the compiled decision of every transition of a batch, with the
    exact fallback: what :meth:`..collision.CollisionChecker.transitions_clear`
    decides (``ordered=0``), for 2-D checkers. P0 must be symmetric."""
    F, nf, n_obs, VE = hazard_arrays(checker)
    n = x0.shape[0]
    status = np.zeros(n, dtype=np.int64)
    decide_batch(np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(P0, dtype=float),
                 np.ascontiguousarray(x1, dtype=float), np.ascontiguousarray(W_e, dtype=float), F, nf, n_obs, VE,
                 checker.thr, checker.thr_witness, _DEPTH, np.zeros((_DEPTH + 4, 10)),
                 np.zeros(max(nf.size, 1), dtype=np.bool_), status)
    clear = status == CLEAR
    ex = (status == EXACT).nonzero()[0]
    if ex.size:
        clear[ex] = exact_clear(checker, x0[ex], P0[ex], x1[ex], W_e[ex])
    return clear


def exact_clear(checker, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, W_e: np.ndarray) -> np.ndarray:
    """(k,) the numpy checker's last layer, its exact minimiser, on k edges
    the compiled layers left open."""
    k = x0.shape[0]
    return ~checker._exact_rest(x0, x1, P0, W_e, np.arange(k), np.zeros(k, dtype=bool))


class CompiledAttempt:
    """One planner run's compiled attempts (:meth:`iterate`, as the numpy
    :meth:`..iteration.IterationMixin._iterate`).

    Parameters
    ----------
    planner : IGRRTStar
        The planner (options, metric, radius constants, noise).
    checker : CollisionChecker
        Its collision checker: thresholds, hazards, and the exact fallback.
    """

    def __init__(self, planner, checker):
        self.planner = planner
        o, sc = planner.options, planner.scenario
        self.F, self.nf, self.n_obs, self.VE = hazard_arrays(checker)
        self.T = np.ascontiguousarray(np.column_stack([sc.target.A, sc.target.b]))
        W = planner.W_edge
        self.W = W
        prm = np.zeros(11)
        prm[[A.P_THR, A.P_THR_W, A.P_THR_T]] = checker.thr, checker.thr_witness, checker.thr_target
        prm[[A.P_W11, A.P_W12, A.P_W22]] = W[0, 0], W[0, 1], W[1, 1]
        prm[A.P_WEIGHT] = planner.metric.weight
        prm[A.P_GAMMA] = planner.gamma
        prm[A.P_RCAP] = o.radius_cap
        prm[A.P_LOGDET_MAX] = planner._logdet_max
        prm[A.P_EIG_FLOOR] = _EIG_FLOOR_FACTOR * o.eig_range[0]
        self.prm = prm
        self.iprm = np.array([0 if o.metric == "entropy" else 1, planner.per_metre, o.steering == "geodesic",
                              _DEPTH], dtype=np.int64)
        self.stack = np.zeros((_DEPTH + 4, 10))
        self.pend = np.zeros(max(self.nf.size, 1), dtype=np.bool_)
        self.out = np.zeros(16)
        self.stats = np.zeros(8, dtype=np.int64)
        self.ibuf = self.fbuf = None
        self.bnb_option = o.branch_and_bound

    def warm_up(self, tree, sample: tuple[np.ndarray, np.ndarray]) -> float:
        """Compile both compiled entry points, or load them from numba's
        cache, before the planner's clock runs (a first numba plan on a
        machine compiles for about 12 s, which a time limit must not count):
        one attempt on ``sample`` against the tree as it is (the root) and a
        rewiring call with no edges; both only write scratch buffers and the
        counters, which are reset. ``sample`` comes from a stream like the
        run's, so the argument types (and the compiled specialisation) are
        the run's. Returns the seconds it took."""
        t0 = time.perf_counter()
        xs, Ps = sample
        self._buffers(tree.x.shape[0])
        ibuf, fbuf = self.ibuf, self.fbuf
        A.attempt(xs, Ps, tree.x, tree.pe, tree.le, tree.cost, tree.h, tree.live, tree.n, self.F, self.nf,
                  self.n_obs, self.VE, self.T, self.prm, self.iprm, math.inf, False, ibuf, fbuf, self.stack,
                  self.pend, self.out, self.stats)
        x0, x1 = (float(v) for v in xs)
        A.decide_rewires(x0, x1, float(Ps[0, 0]), float(Ps[0, 1]), float(Ps[1, 1]), 0.0, 0, tree.x, tree.cost,
                         self.F, self.nf, self.n_obs, self.VE, self.prm, self.iprm, ibuf, fbuf, self.stack,
                         self.pend, self.stats)
        self.stats[:] = 0
        return time.perf_counter() - t0

    def _buffers(self, cap: int) -> None:
        if self.ibuf is None or self.ibuf.shape[1] < cap:
            self.ibuf = np.zeros((5, cap), dtype=np.int64)
            self.fbuf = np.zeros((10, cap))

    def _exact_clear(self, checker, x0, P0, x1, w) -> np.ndarray:
        """(k,) :func:`exact_clear` of k edges whose noise is w times W."""
        return exact_clear(checker, x0, P0, x1, w[:, None, None] * self.W)

    def iterate(self, samples, checker, tree, best: float) -> int | None:
        """One sampling attempt; returns the new node's index or None."""
        pl = self.planner
        st, tm = pl._stats, pl._timings
        t0 = time.perf_counter()
        xs, Ps, _ = samples.next()
        self._buffers(tree.x.shape[0])
        bnb = self.bnb_option and best < np.inf
        ibuf, fbuf, out = self.ibuf, self.fbuf, self.out
        code, nc, nr, pos, goal, r_exact = A.attempt(
            xs, Ps, tree.x, tree.pe, tree.le, tree.cost, tree.h, tree.live, tree.n, self.F, self.nf, self.n_obs,
            self.VE, self.T, self.prm, self.iprm, best, bnb, ibuf, fbuf, self.stack, self.pend, out, self.stats)
        t1 = time.perf_counter()
        tm["compiled"] = tm.get("compiled", 0.0) + (t1 - t0)
        if code == A.IN_HAZARD:
            st["rejected_in_hazard"] += 1
            return None
        if code == A.TOO_SMALL:
            st["rejected_too_small"] += 1
            return None
        if code == A.NO_CANDIDATE:
            st["rejected_no_candidate"] += 1
            return None
        x0, x1, p11, p12, p22, l11, l21, l22, _, h_q = out[:10].tolist()
        x = np.array([x0, x1])
        P = np.array([[p11, p12], [p12, p22]])
        per_metre = self.iprm[A.I_PER_METRE]
        if code == A.PARENT_EXACT:
            upto = pos + 1 if pos >= 0 else nc
            stat = ibuf[A.I_CSTAT, :upto]
            ex = (stat == EXACT).nonzero()[0]
            nodes = ibuf[A.I_CAND, ex]
            w = fbuf[A.F_CDIST, ex] if per_metre else np.ones(ex.size)
            ok = self._exact_clear(checker, tree.x[nodes], tree.P[nodes], np.broadcast_to(x, (ex.size, 2)), w)
            clear = stat == CLEAR
            clear[ex] = ok
            hit = clear.nonzero()[0]
            pos = int(hit[0]) if hit.size else -1
            if pos >= 0:
                cost_q = float(fbuf[A.F_VIA, pos])
                out[10], out[11] = cost_q, fbuf[A.F_CINFO, pos]
                if nr and not (bnb and cost_q + h_q > best * (1 + _REL_EPS)):
                    r_exact = A.decide_rewires(x0, x1, p11, p12, p22, cost_q, nr, tree.x, tree.cost, self.F, self.nf,
                                               self.n_obs, self.VE, self.prm, self.iprm, ibuf, fbuf, self.stack,
                                               self.pend, self.stats)
                else:
                    nr = 0
        t2 = time.perf_counter()
        tm["collision"] += t2 - t1
        if code == A.ALL_COLLIDING or pos < 0:
            st["rejected_all_colliding"] += 1
            return None

        parent = int(ibuf[A.I_CAND, pos])
        cost_q, info_q = out[10], out[11]
        L = np.array([[l11, 0.0], [l21, l22]])
        Linv = np.array([[1.0 / l11, 0.0], [-l21 / (l11 * l22), 1.0 / l22]])
        q = pl._insert(tree, x, P, parent, cost_q, info_q, h_q, bool(goal), L, Linv, bnb, best)
        if not tree.live[q]:
            tm["rewire"] += time.perf_counter() - t2
            return q
        if nr:
            stat = ibuf[A.I_RSTAT, :nr]
            good = stat == CLEAR
            if r_exact:
                ex = (stat == EXACT).nonzero()[0]
                nodes = ibuf[A.I_RW, ex]
                w = fbuf[A.F_RDIST, ex] if per_metre else np.ones(ex.size)
                good[ex] = self._exact_clear(checker, np.broadcast_to(x, (ex.size, 2)),
                                             np.broadcast_to(P, (ex.size, 2, 2)), tree.x[nodes], w)
            good = good.nonzero()[0]
            if good.size:
                pl._rewire(tree, q, ibuf[A.I_RW, good], cost_q + fbuf[A.F_RD, good], fbuf[A.F_RINFO, good], bnb, best)
        tm["rewire"] += time.perf_counter() - t2
        return q

    def flush(self, stats: dict, collision_stats: dict) -> None:
        """Add the compiled counters to the run's ``stats`` and the checker's."""
        s = self.stats.tolist()
        stats["parent_candidates"] += s[A.STAT_PARENTS]
        stats["rewire_candidates"] += s[A.STAT_REWIRES]
        collision_stats["edges"] += s[A.STAT_EDGES]
        collision_stats["edges_screened"] += s[A.STAT_SCREENED] + s[A.STAT_WITNESSED]
        collision_stats["edges_refined"] += s[A.STAT_REFINED]
        collision_stats["ellipses"] += s[A.STAT_ELLIPSES]
        self.stats[:] = 0
