"""One sampling attempt of IG-RRT* (steps 1-7 of :mod:`.rrt`), as a mixin of the planner.

Sample, nearest, steer, shrink, parent, rewire, goal: see the module
docstring of :mod:`.rrt` for what each step does. This file holds how, with
the per-attempt numpy calls kept few, because an attempt is a few hundred
microseconds of mostly call overhead: in 2-D the edge costs come from the
closed-form kernels on the entries of the priors and factors
(:meth:`.metrics.EdgeMetric.edges2`, cached per tree change in the tree's
:class:`~.tree.LiveView`), and all the edges of an attempt go to the
collision checker in one batch.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .collision import CollisionChecker
from .kernels import ROWS_S, _any, _const, _max, chol2, chol_factors, chol_pair2, eigh2, eigh_single
from .sampling import SampleStream
from .tree import BeliefTree, LiveView

__all__ = ["IterationMixin"]

_REL_EPS = 1e-12           # relative tie tolerance for cost comparisons
_EIG_FLOOR_FACTOR = 1e-3   # samples shrunk below 1e-3 * eig_range[0] are rejected
_BELOW = _const(1 - _REL_EPS)


def _distances(x: np.ndarray, live: LiveView) -> np.ndarray:
    """Euclidean distances from x to the live nodes. In 2-D from the
    coordinate rows (the same values as the einsum over (n, 2), a fifth of
    its time on the planner's few hundred nodes): both differences in one
    call on the (2, n) rows (an array op, not two with a Python scalar),
    then d0 * d0 + d1 * d1 as before."""
    if live.xc is not None:
        d = x[:, None] - live.xc
        d *= d
        return np.sqrt(d[0] + d[1])
    diff = x - live.x
    return np.sqrt(np.einsum("ij,ij->i", diff, diff))


class IterationMixin:
    """Steps 1-7 of IG-RRT* for :class:`~.rrt.IGRRTStar` (which sets the
    attributes used here: options, metric, W_edge, per_metre, dim, gamma,
    _tA, _tb, _logdet_max, _stats, _timings)."""

    # ---------------------------------------------------------------- helpers
    def _h(self, x: np.ndarray, logdet_P: float) -> float:
        dist = max(0.0, float(_max(self._tA @ x - self._tb)))     # (the ufunc reduce: no method wrapper)
        if self.metric.metric != "entropy":
            return dist
        return dist + self.metric.weight * max(0.0, 0.5 * (logdet_P - self._logdet_max))

    def _steer(self, xn: np.ndarray, Pn: np.ndarray, xs: np.ndarray, Ps: np.ndarray,
               t: float) -> tuple[np.ndarray, np.ndarray]:
        """Move the sample (xs, Ps) to the fraction t of the way from the nearest node (xn, Pn).

        ``"linear"`` (the authors): x and P interpolated linearly (t = 1 keeps
        the sample). ``"geodesic"``: x interpolated; with P_hat the prior
        predicted from the node to the new mean, and P_s = L U D U^T L^T
        (P_hat = L L^T), P = L U min(D, 1)^t U^T L^T: the matrix-geometric
        interpolation from P_hat toward the matrix minimum of (P_hat, P_s). It
        is below P_hat, so the step from the nearest node is always lossless,
        and its information is t times that of the full step; with t = r / D
        the nearest node is always a parent candidate. (Eigenvalues are capped
        at 1 - 1e-6 so that every step senses a little: an exactly sensing-free
        direction would make S = P^-1 - P_hat^-1 a rounding-noise matrix.)
        """
        if self.options.steering == "linear":
            x = xn + t * (xs - xn)
            P = Pn + t * (Ps - Pn)
            return x, 0.5 * (P + P.T)
        if self.dim == 2:
            return self._steer2(xn, Pn, xs, Ps, t)
        return self._steer_generic(xn, Pn, xs, Ps, t)

    def _steer_generic(self, xn: np.ndarray, Pn: np.ndarray, xs: np.ndarray, Ps: np.ndarray,
                       t: float) -> tuple[np.ndarray, np.ndarray]:
        """The geodesic :meth:`_steer` in numpy, any dimension."""
        x = xn + t * (xs - xn)
        w = float(np.linalg.norm(x - xn)) if self.per_metre else 1.0
        P_hat = Pn + w * self.W_edge
        try:
            # (chol_factors reads the symmetric part: no need to form it)
            L, Linv, _, _ = chol_factors(P_hat)
        except np.linalg.LinAlgError:  # singular prior (P0 = 0 and no motion): keep the sample's P
            return x, Ps
        lam, U = eigh_single(Linv @ Ps @ Linv.T)
        # elementwise in Python floats (the same values as numpy's, fewer calls)
        lam = np.array([min(min(max(v, 1e-300), 1.0) ** t, 1.0 - 1e-6) for v in lam.tolist()])
        LU = L @ U
        P = (LU * lam) @ LU.T
        return x, 0.5 * (P + P.T)

    def _steer2(self, xn: np.ndarray, Pn: np.ndarray, xs: np.ndarray, Ps: np.ndarray,
                t: float) -> tuple[np.ndarray, np.ndarray]:
        """The geodesic :meth:`_steer` in 2-D, the same values with fewer numpy
        calls: what numpy computed elementwise (the interpolated mean, the
        prior, the factors, the eigen-decomposition, the symmetric part) in
        Python floats, in the same order of operations (IEEE 754 rounds
        them the same); the matrix products stay numpy's (its BLAS fuses
        multiply-adds, which plain floats cannot repeat)."""
        (xn0, xn1), (xs0, xs1) = xn.tolist(), xs.tolist()
        x = np.array([xn0 + t * (xs0 - xn0), xn1 + t * (xs1 - xn1)])
        w = float(np.linalg.norm(x - xn)) if self.per_metre else 1.0
        (p00, p01), (p10, p11) = Pn.tolist()
        w00, w01, w10, w11 = self._W4
        try:
            l11, l21, l22, _, _, _ = chol2(p00 + w * w00, p01 + w * w01, p10 + w * w10, p11 + w * w11)
        except np.linalg.LinAlgError:  # singular prior (P0 = 0 and no motion): keep the sample's P
            return x, Ps
        L, Linv = chol_pair2(l11, l21, l22)
        (a, b01), (b10, c) = (Linv @ Ps @ Linv.T).tolist()
        big, small, co, si = eigh2(a, b01, b10, c)
        lam = np.array([min(min(max(v, 1e-300), 1.0) ** t, 1.0 - 1e-6) for v in (big, small)])
        LU = L @ np.array([[co, -si], [si, co]])
        (p00, p01), (p10, p11) = ((LU * lam) @ LU.T).tolist()
        # 0.5 (P + P^T) entry by entry (a sum is the same in either order)
        return x, np.array([[0.5 * (p00 + p00), 0.5 * (p01 + p10)], [0.5 * (p10 + p01), 0.5 * (p11 + p11)]])

    def _noise_stack(self, n: int) -> np.ndarray:
        """(n, d, d) copies of the per-step noise W (a read-only view of a
        stack kept between attempts, grown by doubling)."""
        stack = getattr(self, "_W_stack", None)
        if stack is None or stack.shape[0] < n:
            stack = np.empty((max(64, 2 * n),) + self.W_edge.shape)
            stack[:] = self.W_edge
            stack.setflags(write=False)
            self._W_stack = stack
        return stack[:n]

    def _radius(self, n_live: int) -> float:
        n = n_live + 1
        return min(self.options.radius_cap, self.gamma * (math.log(n) / n) ** (1.0 / self.dim))

    def _priors(self, live: LiveView, w: np.ndarray | None, rows=None) -> np.ndarray:
        """(3, k) entries of the priors P_i + w_i W of the live nodes (``rows``
        of them, default all): per step (w = None) cached with the live view,
        per metre from the weights w (k,)."""
        if w is None:
            prior = live.extra.get("prior")
            if prior is None:
                prior = live.extra["prior"] = live.pe + self._W_entries
            return prior if rows is None else prior.take(rows, axis=1)
        pe = live.pe if rows is None else live.pe.take(rows, axis=1)
        return pe + self._W_entries * w

    # --------------------------------------------------------------- iterate
    def _iterate(self, samples: SampleStream, checker: CollisionChecker, tree: BeliefTree,
                 best: float) -> int | None:
        """One sampling attempt; returns the new node's index or None."""
        o = self.options
        st, tm = self._stats, self._timings
        metric = self.metric
        W = self.W_edge
        per_metre = self.per_metre
        entries = self._entries
        bnb = o.branch_and_bound and math.isfinite(best)
        t0 = time.perf_counter()

        live = tree.live_arrays()
        live_idx, X = live.idx, live.x
        r = self._radius(live_idx.size)
        xs, Ps, lin = samples.next()

        # nearest in the (matrix-minimum) edge cost, then steer
        dist = _distances(xs, live)
        if entries and lin is not None:
            # the priors' entries as the kernel's stack of six rows (cached per step)
            S6 = live.extra.get("prior6") if not per_metre else None
            if S6 is None:
                S6 = self._priors(live, dist if per_metre else None).take(ROWS_S, axis=0)
                if not per_metre:
                    live.extra["prior6"] = S6
            info = metric.nearest_info2_rows(S6, *lin)
        else:
            _, Ls_inv, _, _ = chol_factors(Ps)
            info = metric.nearest_info(live.P, dist if per_metre else np.ones_like(dist), Ps, Ls_inv)
        D = dist + metric.weight0 * info
        j = int(D.argmin())
        Dj = D[j]
        t = min(1.0, r / Dj) if Dj > 0 else 1.0
        x, P = self._steer(X[j], tree.P[live_idx[j]], xs, Ps, t)

        # shrink until the ellipse is clear (exact distance -> number of halvings)
        k = checker.shrink_exponent(x, P)
        if k is None:
            st["rejected_in_hazard"] += 1
            tm["sample"] += time.perf_counter() - t0
            return None
        if k:
            P = P * 0.5 ** k
        try:
            L, Linv, logdet, eig_min = chol_factors(P)
        except np.linalg.LinAlgError:
            eig_min = 0.0
        if not eig_min >= _EIG_FLOOR_FACTOR * o.eig_range[0]:
            st["rejected_too_small"] += 1
            tm["sample"] += time.perf_counter() - t0
            return None
        t1 = time.perf_counter()
        tm["sample"] += t1 - t0

        # parent candidates: live nodes with a lossless edge of cost <= r (cost >= distance)
        dist = _distances(x, live)
        r0 = np.array(r)                    # 0-d, compared thrice (see kernels._const)
        near = (dist <= r0).nonzero()[0]
        if near.size == 0:
            st["rejected_no_candidate"] += 1
            tm["candidates"] += time.perf_counter() - t1
            return None
        dn = dist[near]
        k = near.size
        # (rewiring: the root is among the neighbours, but never rewired: its
        # cost 0 cannot be lowered, so the cost test below drops it)
        nn = live_idx[near]
        if entries:
            # the edges to q from its neighbours and from q to them (for
            # rewiring, used unless q is hopeless) in one kernel call: rows
            # (s11, s12, s22) of the priors and (t11, t21, t22) of the factors
            S = np.empty((6, 2 * k))
            S[:3, :k] = self._priors(live, dn if per_metre else None, near)
            # (scalar fills: cheaper than gathering the entries of 2x2 arrays)
            (t11, _), (t21, t22) = Linv.tolist()
            S[3, :k], S[4, :k], S[5, :k] = t11, t21, t22
            (p11, p12), (_, p22) = P.tolist()
            if per_metre:
                S[:3, k:] = np.array([[p11], [p12], [p22]]) + self._W_entries * dn
            else:
                w11, w12, w22 = self._W_list
                S[0, k:], S[1, k:], S[2, k:] = p11 + w11, p12 + w12, p22 + w22
            S[3:, k:] = tree.le.take(nn, axis=1)
            lossless_all, info_all = metric.edges2_rows(S)
            lossless, info = lossless_all[:k], info_all[:k]
        else:
            lossless, info = metric.edges_to(live.P[near], dn if per_metre else np.ones(near.size), P, L, Linv)
        Dn = metric.cost(dn, info)
        ok = lossless & (Dn <= r0)
        cand = near[ok]                         # positions in live_idx
        if cand.size == 0:
            st["rejected_no_candidate"] += 1
            tm["candidates"] += time.perf_counter() - t1
            return None
        c_D, c_info = Dn[ok], info[ok]
        via = tree.cost[nn[ok]] + c_D
        order = via.argsort(kind="stable")
        c_lb = float(via[order[0]])
        h_q = self._h(x, logdet)
        hopeless = bnb and c_lb + h_q > best * (1 + _REL_EPS)
        st["parent_candidates"] += cand.size

        # rewiring candidates (superset, with the optimistic cost c_lb of q)
        rw = None
        if not hopeless:
            rv, nodes, dr = near, nn, dn
            if entries:
                lossless_r, info_r = lossless_all[k:], info_all[k:]
            else:
                wr = dr if per_metre else np.ones(rv.size)
                lossless_r, info_r = metric.edges_from(P, wr, tree.P[nodes], tree.L[nodes], tree.Linv[nodes])
            Dr = metric.cost(dr, info_r)
            new_lb = c_lb + Dr
            okr = lossless_r & (Dr <= r0) & (new_lb < tree.cost[nodes] * _BELOW)
            if bnb:
                okr &= new_lb + tree.h[nodes] <= best * (1 + _REL_EPS)
            if _any(okr):
                rw = rv[okr]
                r_D, r_info, r_d = Dr[okr], info_r[okr], dr[okr]
                st["rewire_candidates"] += rw.size
        t2 = time.perf_counter()
        tm["candidates"] += t2 - t1

        # collision checks, one batch: every parent candidate in order (only the
        # first clear one matters, so the checker stops deciding after it) and
        # every rewiring edge
        nc = order.size
        nr = 0 if rw is None else rw.size
        d = self.dim
        x0 = np.empty((nc + nr, d))
        P0 = np.empty((nc + nr, d, d))
        x1 = np.empty((nc + nr, d))
        pn = live_idx[cand[order]]
        tree.x.take(pn, axis=0, out=x0[:nc])
        tree.P.take(pn, axis=0, out=P0[:nc])
        x1[:nc] = x
        if nr:
            x0[nc:] = x
            P0[nc:] = P
            X.take(rw, axis=0, out=x1[nc:])
        if per_metre:
            We = np.concatenate([dn[ok][order], r_d] if nr else [dn[ok][order]])[:, None, None] * W
        else:
            We = self._noise_stack(nc + nr)
        clear = checker.transitions_clear(x0, P0, x1, We, ordered=nc)
        hit = clear[:nc].nonzero()[0]
        parent_pos = int(order[hit[0]]) if hit.size else -1
        t3 = time.perf_counter()
        tm["collision"] += t3 - t2
        if parent_pos < 0:
            st["rejected_all_colliding"] += 1
            return None

        parent = int(live_idx[cand[parent_pos]])
        cost_q = float(via[parent_pos])
        goal = checker.in_target(x, P)
        q = self._insert(tree, x, P, parent, cost_q, float(c_info[parent_pos]), h_q, goal, L, Linv, bnb, best)
        if not tree.live[q]:
            tm["rewire"] += time.perf_counter() - t3
            return q

        # rewire (cheapest new cost first)
        if nr:
            good = clear[nc:].nonzero()[0]
            if good.size:
                self._rewire(tree, q, live_idx[rw[good]], cost_q + r_D[good], r_info[good], bnb, best)
        tm["rewire"] += time.perf_counter() - t3
        return q

    def _insert(self, tree: BeliefTree, x: np.ndarray, P: np.ndarray, parent: int, cost_q: float, info: float,
                h_q: float, goal: bool, L: np.ndarray, Linv: np.ndarray, bnb: bool, best: float) -> int:
        """Add the new node; one that cannot lead to a better path is dead on
        arrival (not live; counted, as the authors' node that their next
        branch-and-bound step removes)."""
        q = tree.add(x, P, parent, cost_q, info, h_q, goal, L=L, Linv=Linv)
        if bnb and cost_q + h_q > best * (1 + _REL_EPS):
            tree.set_live(q, False)
            self._stats["hopeless_nodes"] += 1
            self._stats["pruned"] += 1
        return q

    def _rewire(self, tree: BeliefTree, q: int, nodes: np.ndarray, new_cost: np.ndarray, infos: np.ndarray,
                bnb: bool, best: float) -> None:
        """Rewire the ``nodes`` (their edges from q proven clear) under q,
        cheapest new cost first; each is re-checked against the current
        costs, since an earlier rewire in this loop may already have lowered
        its subtree."""
        anc = tree.ancestors(q)
        for i in new_cost.argsort(kind="stable").tolist():
            v = int(nodes[i])
            nc_v = float(new_cost[i])
            if v in anc or not tree.live[v] or not nc_v < tree.cost[v] * (1 - _REL_EPS):
                continue
            sub = tree.reparent(v, q, nc_v, float(infos[i]))
            self._stats["rewires"] += 1
            if bnb:
                self._revive(tree, sub, best)

    def _revive(self, tree: BeliefTree, sub: list[int], best: float) -> None:
        """Nodes pruned earlier whose cost dropped with a rewired ancestor come back."""
        idx = np.asarray(sub)
        back = idx[~tree.live[idx] & (tree.cost[idx] + tree.h[idx] <= best * (1 + _REL_EPS))]
        if back.size:
            tree.set_live(back, True)
            self._stats["revived"] += back.size
