"""One IG-RRT* attempt in 2-D, compiled: sample factor, nearest, steer, shrink,
candidates and their edge costs, and the collision decisions of its edges.

The steps and tests are those of :meth:`..iteration.IterationMixin._iterate`
(see there and :mod:`..rrt` for why); what differs is how:

* the tree is read in place (its preallocated arrays: means ``tx`` (cap, 2),
  covariance entries ``tpe`` and inverse-factor entries ``tle`` (3, cap),
  ``tcost``, ``th``, ``tlive``), the live nodes by a scan of the first n;
* parent candidates are decided one at a time in order of cost through them,
  up to the first clear one (the numpy checker screens them all first);
* rewiring edges are decided only when the new node is live, and only those
  that would lower the neighbour's cost through the new node's actual cost
  (the rewiring loop re-checks that condition anyway);
* an edge the layers cannot decide is reported (``EXACT``), and the caller
  decides it with the exact minimiser, as the numpy checker does.

Buffers: ``ibuf`` (int64, 5 x cap) and ``fbuf`` (float64, 10 x cap) rows
(see ``I_*``, ``F_*``), ``out`` (float64, 16): the new node and its
numbers, ``stats`` (int64, 8): counters (``STAT_*``).
"""

from __future__ import annotations

import math

from numba import njit

from ..iteration import _REL_EPS as REL_EPS
from .collide import CLEAR, EXACT, decide_edge, in_target, shrink_exponent
from .linalg import LOSSLESS_MIN, chol2, congruence_pair, info_pair, inv_factor, steer

# attempt outcomes
IN_HAZARD, TOO_SMALL, NO_CANDIDATE, ALL_COLLIDING, NODE, PARENT_EXACT = 1, 2, 3, 4, 5, 6
SKIPPED = 3                 # a rewiring edge not decided (it could not lower the cost)
# rows of ibuf / fbuf
I_CAND, I_CSTAT, I_RW, I_RSTAT, I_NEAR = 0, 1, 2, 3, 4
F_VIA, F_CINFO, F_CDIST, F_RD, F_RINFO, F_RDIST, F_ND, F_NINFO, F_NDIST, F_NVIA = range(10)
# counters
STAT_EDGES, STAT_SCREENED, STAT_WITNESSED, STAT_REFINED, STAT_EXACT, STAT_PARENTS, STAT_REWIRES, STAT_ELLIPSES = \
    range(8)
# prm (float) and iprm (int) entries
P_THR, P_THR_W, P_THR_T, P_W11, P_W12, P_W22, P_WEIGHT, P_GAMMA, P_RCAP, P_LOGDET_MAX, P_EIG_FLOOR = range(11)
I_METRIC, I_PER_METRE, I_GEODESIC, I_DEPTH = range(4)


@njit(cache=True, error_model="numpy")
def stable_order(key, n, order, tmp) -> None:
    """``order[:n]`` = the stable ascending order of ``key[:n]`` (numpy's
    ``argsort(kind="stable")`` for keys without NaN), by a bottom-up merge
    sort; ``tmp`` (>= n) is scratch. (numpy's argsort in numba costs about
    3 s of compilation.)"""
    for i in range(n):
        order[i] = i
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid, hi = min(lo + width, n), min(lo + 2 * width, n)
            i, j = lo, mid
            for k in range(lo, hi):
                # the left run wins ties: stable
                if j < hi and (i >= mid or key[order[j]] < key[order[i]]):
                    tmp[k] = order[j]
                    j += 1
                else:
                    tmp[k] = order[i]
                    i += 1
        for k in range(n):
            order[k] = tmp[k]
        width *= 2


@njit(cache=True, error_model="numpy")
def cost_to_go(x0, x1, logdet, T, weight, entropy, logdet_max) -> float:
    """:meth:`..iteration.IterationMixin._h`."""
    dist = -math.inf
    for f in range(T.shape[0]):
        dist = max(dist, T[f, 0] * x0 + T[f, 1] * x1 - T[f, 2])
    dist = max(0.0, dist)
    if not entropy:
        return dist
    return dist + weight * max(0.0, 0.5 * (logdet - logdet_max))


@njit(cache=True, error_model="numpy")
def decide_rewires(x0, x1, p11, p12, p22, cost_q, nr, tx, tcost, F, nf, n_obs, VE, prm, iprm, ibuf, fbuf,
                   stack, pend, stats) -> int:
    """Collision statuses (ibuf row I_RSTAT) of the rewiring edges q -> v that
    would lower v's cost through q's cost ``cost_q``; the others SKIPPED.
    Returns how many need the exact check."""
    per_metre = iprm[I_PER_METRE]
    w11, w12, w22 = prm[P_W11], prm[P_W12], prm[P_W22]
    n_exact = 0
    for i in range(nr):
        v = ibuf[I_RW, i]
        if not cost_q + fbuf[F_RD, i] < tcost[v] * (1 - REL_EPS):
            ibuf[I_RSTAT, i] = SKIPPED
            continue
        w = fbuf[F_RDIST, i] if per_metre else 1.0
        st, stage = decide_edge(x0, x1, tx[v, 0], tx[v, 1], p11, p12, p22, w * w11, w * w12, w * w22, F, nf, n_obs,
                                VE, prm[P_THR], prm[P_THR_W], iprm[I_DEPTH], stack, pend)
        ibuf[I_RSTAT, i] = st
        stats[STAT_EDGES] += 1
        stats[STAT_SCREENED + stage] += 1
        if st == EXACT:
            n_exact += 1
    stats[STAT_EXACT] += n_exact
    return n_exact


@njit(cache=True, error_model="numpy")
def attempt(xs, Ps, tx, tpe, tle, tcost, th, tlive, n, F, nf, n_obs, VE, T, prm, iprm, best, bnb, ibuf, fbuf,
            stack, pend, out, stats):
    """One attempt on the sample (xs, Ps). Returns (outcome, number of parent
    candidates, number of rewiring candidates, position of the parent in the
    candidate order or -1, goal, rewiring edges needing the exact check);
    ``out`` holds x0, x1, p11, p12, p22, l11, l21, l22, logdet, h, cost,
    info, radius of the new node (outcomes NODE and PARENT_EXACT; cost and
    info for NODE only)."""
    metric, per_metre = iprm[I_METRIC], iprm[I_PER_METRE]
    w11, w12, w22 = prm[P_W11], prm[P_W12], prm[P_W22]
    weight = prm[P_WEIGHT]
    # the sample's inverse factor (SampleStream's formulas)
    s11, s12, s22 = Ps[0, 0], 0.5 * (Ps[0, 1] + Ps[1, 0]), Ps[1, 1]
    xs0, xs1 = xs[0], xs[1]
    l11, l21, l22, ok = chol2(s11, s12, s22)
    if not ok:
        return TOO_SMALL, 0, 0, -1, False, 0
    i11, i21, i22 = inv_factor(l11, l21, l22)

    # nearest live node in the (matrix-minimum) edge cost
    n_live = 0
    j = -1
    Dj = math.inf
    for i in range(n):
        if not tlive[i]:
            continue
        n_live += 1
        d0, d1 = xs0 - tx[i, 0], xs1 - tx[i, 1]
        dist = math.sqrt(d0 * d0 + d1 * d1)
        w = dist if per_metre else 1.0
        small, big = congruence_pair(tpe[0, i] + w * w11, tpe[1, i] + w * w12, tpe[2, i] + w * w22, i11, i21, i22)
        D = dist + weight * info_pair(small, big, 1.0, metric)
        if j < 0 or D < Dj:
            j, Dj = i, D
    nl = n_live + 1.0
    r = min(prm[P_RCAP], prm[P_GAMMA] * (math.log(nl) / nl) ** 0.5)
    t = min(1.0, r / Dj) if Dj > 0 else 1.0
    x0, x1, p11, p12, p22 = steer(tx[j, 0], tx[j, 1], tpe[0, j], tpe[1, j], tpe[2, j], xs0, xs1, s11, s12, s22,
                                  t, w11, w12, w22, per_metre, iprm[I_GEODESIC])

    # shrink until the ellipse is clear
    stats[STAT_ELLIPSES] += 1
    k = shrink_exponent(x0, x1, p11, p12, p22, F, nf, n_obs, VE, prm[P_THR])
    if k < 0:
        return IN_HAZARD, 0, 0, -1, False, 0
    if k:
        f = 0.5 ** k
        p11, p12, p22 = p11 * f, p12 * f, p22 * f
    l11, l21, l22, ok = chol2(p11, p12, p22)
    if not ok:
        return TOO_SMALL, 0, 0, -1, False, 0
    det = (l11 * l22) ** 2
    hd = 0.5 * (p11 - p22)
    big = 0.5 * (p11 + p22) + math.sqrt(hd * hd + p12 * p12)
    if not det / big >= prm[P_EIG_FLOOR]:
        return TOO_SMALL, 0, 0, -1, False, 0
    logdet = math.log(det)
    q11, q21, q22 = inv_factor(l11, l21, l22)
    out[0], out[1], out[2], out[3], out[4] = x0, x1, p11, p12, p22
    out[5], out[6], out[7], out[8], out[12] = l11, l21, l22, logdet, r

    # neighbours: parent candidates (edges v -> q) and rewiring edges (q -> v)
    nn = 0
    nc = 0
    for i in range(n):
        if not tlive[i]:
            continue
        d0, d1 = x0 - tx[i, 0], x1 - tx[i, 1]
        dist = math.sqrt(d0 * d0 + d1 * d1)
        if not dist <= r:
            continue
        w = dist if per_metre else 1.0
        small, big = congruence_pair(tpe[0, i] + w * w11, tpe[1, i] + w * w12, tpe[2, i] + w * w22, q11, q21, q22)
        info = info_pair(small, big, 1e-300, metric)
        Dn = dist + weight * info
        # (the nearest node's edge to a steered sample costs r in exact
        # arithmetic; rounding decides whether it is a candidate, here as in
        # the numpy attempt: a tolerance would change the search, docs/planner.md)
        if small >= LOSSLESS_MIN and Dn <= r:
            ibuf[I_CAND, nc] = i
            fbuf[F_NVIA, nc] = tcost[i] + Dn
            fbuf[F_CINFO, nc] = info
            fbuf[F_CDIST, nc] = dist
            nc += 1
        small, big = congruence_pair(p11 + w * w11, p12 + w * w12, p22 + w * w22, tle[0, i], tle[1, i], tle[2, i])
        info = info_pair(small, big, 1e-300, metric)
        Dr = dist + weight * info
        if small >= LOSSLESS_MIN and Dr <= r:
            ibuf[I_NEAR, nn] = i
            fbuf[F_ND, nn] = Dr
            fbuf[F_NINFO, nn] = info
            fbuf[F_NDIST, nn] = dist
            nn += 1
    if nc == 0:
        return NO_CANDIDATE, 0, 0, -1, False, 0
    stats[STAT_PARENTS] += nc
    # candidates in order of cost through them (stable, as the numpy path)
    stable_order(fbuf[F_NVIA], nc, ibuf[I_RW], ibuf[I_RSTAT])      # (rewiring rows: filled below)
    for p in range(nc):
        o = ibuf[I_RW, p]
        fbuf[F_VIA, p] = fbuf[F_NVIA, o]
        ibuf[I_CSTAT, p] = ibuf[I_CAND, o]        # (scratch rows: the sorted candidates, moved below)
        fbuf[F_RINFO, p] = fbuf[F_CINFO, o]
        fbuf[F_RDIST, p] = fbuf[F_CDIST, o]
    for p in range(nc):
        ibuf[I_CAND, p] = ibuf[I_CSTAT, p]
        fbuf[F_CINFO, p] = fbuf[F_RINFO, p]
        fbuf[F_CDIST, p] = fbuf[F_RDIST, p]
    c_lb = fbuf[F_VIA, 0]
    h_q = cost_to_go(x0, x1, logdet, T, prm[P_WEIGHT], metric == 0, prm[P_LOGDET_MAX])
    out[9] = h_q
    hopeless = bnb and c_lb + h_q > best * (1 + REL_EPS)
    nr = 0
    if not hopeless:
        for m in range(nn):
            v = ibuf[I_NEAR, m]
            new_lb = c_lb + fbuf[F_ND, m]
            if not new_lb < tcost[v] * (1 - REL_EPS):
                continue
            if bnb and not new_lb + th[v] <= best * (1 + REL_EPS):
                continue
            ibuf[I_RW, nr] = v
            fbuf[F_RD, nr] = fbuf[F_ND, m]
            fbuf[F_RINFO, nr] = fbuf[F_NINFO, m]
            fbuf[F_RDIST, nr] = fbuf[F_NDIST, m]
            nr += 1
    stats[STAT_REWIRES] += nr

    # parents, in order, up to the first clear one
    thr, thr_w, depth = prm[P_THR], prm[P_THR_W], iprm[I_DEPTH]
    parent_pos = -1
    n_exact = 0
    for p in range(nc):
        v = ibuf[I_CAND, p]
        w = fbuf[F_CDIST, p] if per_metre else 1.0
        st, stage = decide_edge(tx[v, 0], tx[v, 1], x0, x1, tpe[0, v], tpe[1, v], tpe[2, v], w * w11, w * w12,
                                w * w22, F, nf, n_obs, VE, thr, thr_w, depth, stack, pend)
        ibuf[I_CSTAT, p] = st
        stats[STAT_EDGES] += 1
        stats[STAT_SCREENED + stage] += 1
        if st == CLEAR:
            parent_pos = p
            break
        if st == EXACT:
            n_exact += 1
    stats[STAT_EXACT] += n_exact
    if parent_pos < 0 and not n_exact:
        return ALL_COLLIDING, nc, nr, -1, False, 0
    goal = in_target(x0, x1, p11, p12, p22, T, prm[P_THR_T])
    if n_exact:
        return PARENT_EXACT, nc, nr, parent_pos, goal, 0
    cost_q = fbuf[F_VIA, parent_pos]
    out[10], out[11] = cost_q, fbuf[F_CINFO, parent_pos]
    r_exact = 0
    if nr and not (bnb and cost_q + h_q > best * (1 + REL_EPS)):
        r_exact = decide_rewires(x0, x1, p11, p12, p22, cost_q, nr, tx, tcost, F, nf, n_obs, VE, prm, iprm, ibuf,
                                 fbuf, stack, pend, stats)
    return NODE, nc, nr, parent_pos, goal, r_exact
