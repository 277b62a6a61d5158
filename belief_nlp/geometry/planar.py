"""The planar path: exact dist2 and its minimum over s for 2-D polygons.

In the plane the nearest point of a polygon lies on an edge or is a vertex,
so min_s dist2(s) splits into per-feature minimisations (see
:func:`_planar_transitions`): edges in closed form, vertex curves from a
Newton guess on their pole form (:func:`_vertex_newton`) checked by a
convexity lower bound, the rare rest by :func:`~.minimise._minimise_brackets`.
It is plain vectorised arithmetic with no fancy indexing, which is what
makes it fast for the small batches a planner issues (d = 2 is by far the
common case); it also returns minimisers and Theorem-1 certificates.
"""

from __future__ import annotations

import numpy as np

from ._numeric import _P_FLOOR
from .minimise import TransitionMinimum, _decided, _minimise_brackets, _mix_certificates
from .polytopes import PolytopeSet, _Planar


# OpenBLAS runs a GEMM multithreaded once M*N*K exceeds 4 * 65536. The
# planar products have K = 7 or 13, so threading buys nothing, and on a
# shared machine waking the threads cost up to 10x (measured: 16 ms vs 1.1 ms
# for 1000 ellipses x 10 polygons on 2 busy cores). Stay under the threshold.
_GEMM_BUDGET = 200_000

# Constants of :func:`_planar_points` as 0-d arrays (the planner calls it on
# a few rows at a time, where an op with a Python scalar or an int literal
# costs 1-2 us more than with a 0-d array in numpy 2.x; the same values), and
# its column of ones sliced from a kept array.
_HALF, _TWO, _ZERO, _INF = (np.array(v) for v in (0.5, 2.0, 0.0, np.inf))
_ONES = np.ones((512, 1))


def _ones(n: int) -> np.ndarray:
    return _ONES[:n] if n <= _ONES.shape[0] else np.ones((n, 1))


def _small_k_matmul(T: np.ndarray, M: np.ndarray) -> np.ndarray:
    """T @ M in row blocks small enough for a single-threaded GEMM."""
    n, k = T.shape
    step = max(1, _GEMM_BUDGET // (k * M.shape[1]))
    if n <= step:
        return T @ M
    out = np.empty((n, M.shape[1]))
    for i in range(0, n, step):
        np.matmul(T[i:i + step], M, out=out[i:i + step])
    return out


def _sym_entries(P: np.ndarray, floor: float = _P_FLOOR) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p11 + floor, symmetrised p12, p22 + floor) of stacked 2x2 matrices."""
    return P[:, 0, 0] + floor, _HALF * (P[:, 0, 1] + P[:, 1, 0]), P[:, 1, 1] + floor


def _planar_points(pl: _Planar, x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """dist2 (n, m) of points x (n, 2) under P (n, 2, 2) to every polygon.

    Outside a convex polygon the nearest point (in the P^-1 metric) is on the
    boundary: either the foot on an edge's line, when it falls inside the
    edge, with value (a^T x - b)^2 / (a^T P a) (paper Remark 1), or a vertex v
    with (v-x)^T P^-1 (v-x). Every such candidate is a point of the polygon,
    so the minimum over all of them is exact; inside, dist2 = 0.
    """
    n = x.shape[0]
    R = _small_k_matmul(np.concatenate([_ones(n), x, P.reshape(n, 4)], axis=1), pl.M_pt)
    E = pl.n_edges
    c, tx, q, tpa = R[:, :E], R[:, E:2 * E], R[:, 2 * E:3 * E], R[:, 3 * E:4 * E]
    mu = c / q
    u = tx + tpa * mu                       # foot y* = x + P a mu, in edge coordinates
    ev = np.where((u >= pl.e_lo) & (u <= pl.e_hi), c * mu, _INF)
    p11, p12, p22 = (v[:, None] for v in _sym_entries(P))
    rx = pl.vx - x[:, :1]
    ry = pl.vy - x[:, 1:]
    vv = (p22 * rx * rx - _TWO * p12 * rx * ry + p11 * ry * ry) / (p11 * p22 - p12 * p12) + pl.v_pen
    d2 = np.minimum(np.minimum.reduceat(ev, pl.e_start, axis=1), np.minimum.reduceat(vv, pl.v_start, axis=1))
    d2[np.minimum.reduceat(R[:, 4 * E:], pl.f_start, axis=1) >= _ZERO] = 0.0      # mean inside
    return d2


def _vertex_curve(s, r0x, r0y, dx, dy, p11, p12, p22, w11, w12, w22, second: bool = True):
    """V(s) = r^T P(s)^-1 r, r = v - x(s), its first two s-derivatives, and z.

    Closed-form 2x2 algebra: z = P^-1 r, V' = -2 dx^T z - z^T W z,
    V'' = 2 e^T P^-1 e with e = -dx - W z (a matrix-fractional function of
    affine data, hence convex). z = P^-1 r gives the Lemma-1 certificate.
    """
    rx = r0x - s * dx
    ry = r0y - s * dy
    a = p11 + s * w11
    b = p12 + s * w12
    c = p22 + s * w22
    det = a * c - b * b
    zx = (c * rx - b * ry) / det
    zy = (a * ry - b * rx) / det
    wzx = w11 * zx + w12 * zy
    wzy = w12 * zx + w22 * zy
    ex = -dx - wzx
    ey = -dy - wzy
    V = rx * zx + ry * zy
    V1 = 2.0 * (ex * zx + ey * zy) + (zx * wzx + zy * wzy)     # = -2 dx^T z - z^T W z
    V2 = 2.0 * (c * ex * ex - 2.0 * b * ex * ey + a * ey * ey) / det if second else None
    return V, V1, V2, zx, zy


def _vertex_newton(r0x, r0y, dx, dy, p11, p12, p22, w11, w12, w22, steps: int = 12):
    """Approximate minimiser in (0, 1) of a vertex curve, for W > 0 (k items).

    Whitening by W = L L^T and diagonalising L^-1 P0 L^-T = U diag(d) U^T
    turn the curve into V(s) = sum_i rho_i(s)^2 / (s + d_i) with rho affine;
    expanding each term around its pole s = -d_i gives

        V(s) = const + C s + sum_i A_i / (s + d_i),   C = dx^T W^-1 dx, A_i >= 0,

    so V'(s) = 0 iff phi(s) = (sum_i A_i (s + d_i)^-2)^(-1/2) = C^(-1/2).
    phi is a power mean (p = -2) of positive affine functions, hence concave
    and increasing, and exactly linear for one term: Newton on it from s = 0
    (left of the root, since V'(0) < 0) climbs monotonically to the root in
    a few steps, where Newton on V' itself crawls near the pole of a tiny
    P_prev. Returns s (NaN where W is not safely positive definite); the
    caller checks it with the convexity lower bound, so this only needs to
    be a good guess.
    """
    ok = (w11 > 0) & (w11 * w22 - w12 * w12 > 1e-12 * w11 * w22)
    l11 = np.sqrt(np.where(ok, w11, 1.0))
    l21 = w12 / l11
    l22 = np.sqrt(np.where(ok, w22 - l21 * l21, 1.0))
    a, b, c = 1 / l11, -l21 / (l11 * l22), 1 / l22                  # L^-1 = [[a, 0], [b, c]]
    m11 = a * a * p11
    m12 = a * (b * p11 + c * p12)
    m22 = b * b * p11 + 2 * b * c * p12 + c * c * p22
    half = 0.5 * (m11 - m22)
    rad = np.hypot(half, m12)
    d1 = 0.5 * (m11 + m22) + rad
    d2 = (m11 * m22 - m12 * m12) / d1                                 # small eigenvalue, no cancellation
    ang = 0.5 * np.arctan2(m12, half)
    cs, sn = np.cos(ang), np.sin(ang)
    # rho(s) = U^T L^-1 (r0 - s dx) = q0 - s q1
    u0x, u0y = a * r0x, b * r0x + c * r0y
    u1x, u1y = a * dx, b * dx + c * dy
    q0 = (cs * u0x + sn * u0y, -sn * u0x + cs * u0y)
    q1 = (cs * u1x + sn * u1y, -sn * u1x + cs * u1y)
    A1 = (q0[0] + d1 * q1[0]) ** 2                                    # rho_i at the pole s = -d_i
    A2 = (q0[1] + d2 * q1[1]) ** 2
    C = q1[0] ** 2 + q1[1] ** 2
    # At the root each term alone is <= C, so s* >= sqrt(A_i / C) - d_i for
    # both i: start there (still left of the root, exact when one term rules).
    d = np.stack([d1, d2])
    A = np.stack([A1, A2])
    s = np.clip(np.max(np.sqrt(A / C) - d, axis=0), 0.0, 1.0)
    for _ in range(steps):
        e = A / (s + d) ** 2
        S = e[0] + e[1]
        step = S * (np.sqrt(S / C) - 1) / (e[0] / (s + d1) + e[1] / (s + d2))
        s = np.minimum(s + step, 1.0)
        if not np.any(step > 1e-15):
            break
    return np.where(ok, s, np.nan)


def _planar_transitions(ps: PolytopeSet, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, W: np.ndarray,
                        tol: float, max_iter: int, threshold: float | None,
                        want_s: bool, want_lam: bool) -> TransitionMinimum:
    """min over s in [0, 1] of dist2(x(s), P(s)) for 2-D polygons, exactly.

    The nearest point of a polygon is an edge foot or a vertex, so

        min_s dist2(s) = min( min over edges e of min_s L_e(s) [foot in e],
                              min over vertices v of min_s V_v(s) )

    where L_e(s) = c(s)^2 / q(s) is the distance to the edge's line (c = b -
    a^T x(s), q = a^T P(s) a, both affine in s) and V_v(s) = (v - x(s))^T
    P(s)^-1 (v - x(s)). Why an edge needs only its line's minimiser: the
    distance to the edge segment is the partial minimum of a jointly convex
    function of (s, u) (matrix-fractional in affine data) over [0, 1] x
    [u_lo, u_hi]; if the relaxed minimiser over [0, 1] x R has its foot u
    outside the edge, the constrained minimum lies on u = u_lo or u_hi, i.e.
    on a vertex curve, which is in the list anyway. Every candidate is a real
    (s, point) pair, so none undercuts the true minimum. A mean path that
    enters the polygon crosses an edge, where L_e = 0 with its foot on the
    edge; one that starts inside gives 0 directly.

    L_e is quadratic-over-linear: L' = c (2 beta q - q1 c) / q^2 with c of
    fixed sign when the path does not cross the line, so the interior
    minimiser is the root of the affine h(s) = 2 beta q(s) - q1 c(s) --
    closed form, no iteration. The vertex curves are smooth and convex; most
    have their minimum at an end (sign of V' there), the rest go to
    :func:`_minimise_brackets`, skipping any whose convexity lower bound
    cannot beat the pair's best value (or change the threshold decision).
    """
    n, m, pl, E = x0.shape[0], len(ps), ps.planar, ps.planar.n_edges
    dxy = x1 - x0
    R = _small_k_matmul(np.concatenate([np.ones((n, 1)), x0, dxy, P0.reshape(n, 4), W.reshape(n, 4)], axis=1),
                        pl.M_tr)
    alpha, beta, tx0, tdx, q0, q1, tp0, tw = (R[:, k * E:(k + 1) * E] for k in range(8))
    inside = np.minimum.reduceat(R[:, 8 * E:], pl.f_start, axis=1) >= 0              # (n, m)

    # ---- edges: closed-form minimiser of L_e over [0, 1]
    c1 = alpha + beta
    Q1 = q0 + q1
    h0 = 2 * beta * q0 - q1 * alpha
    h1 = 2 * beta * Q1 - q1 * c1
    s_e = np.where(c1 * c1 * q0 < alpha * alpha * Q1, 1.0, 0.0)                     # an end
    s_e = np.where((alpha * h0 < 0) & (c1 * h1 > 0), h0 / (h0 - h1), s_e)            # L'(0) < 0 < L'(1)
    s_e = np.where(alpha * c1 <= 0, np.fmin(np.fmax(-alpha / beta, 0.0), 1.0), s_e)   # crosses the line (0/0 -> 0)
    c = alpha + beta * s_e
    mu = c / (q0 + q1 * s_e)
    u = tx0 + s_e * tdx + (tp0 + s_e * tw) * mu
    e_val = np.where((u >= pl.e_lo) & (u <= pl.e_hi), c * mu, np.inf)

    # ---- vertex curves: values and slopes at both ends (axis 0: s = 0, 1)
    p11, p12, p22 = _sym_entries(P0)
    w11, w12, w22 = _sym_entries(W, 0.0)
    per_n = np.stack([dxy[:, 0], dxy[:, 1], p11, p12, p22, w11, w12, w22])           # (8, n)
    r0x = pl.vx - x0[:, :1]
    r0y = pl.vy - x0[:, 1:]
    ends = np.array([0.0, 1.0])[:, None, None]
    V, V1, _, zx, zy = _vertex_curve(ends, r0x, r0y, *per_n[:, :, None], second=False)
    V = V + pl.v_pen
    v_best = np.minimum(V[0], V[1])
    e_min = np.minimum.reduceat(e_val, pl.e_start, axis=1)
    v_min = np.minimum.reduceat(v_best, pl.v_start, axis=1)
    U0 = np.where(inside, 0.0, np.minimum(e_min, v_min))
    U = U0.copy()

    # ---- iterate the vertex curves that can still matter
    nV = V.shape[2]
    v_poly = pl.v_poly
    Uv = U[:, v_poly]
    t = np.minimum(np.maximum((V[1] - V[0] - V1[1]) / (V1[0] - V1[1]), 0.0), 1.0)
    lb0 = V[0] + V1[0] * t
    cand = (V1[0] < 0) & (V1[1] > 0) & (lb0 < Uv - tol * (1.0 + Uv))
    if threshold is not None:
        cand &= (lb0 < threshold) & (Uv >= threshold)
    idx = np.flatnonzero(cand)
    iterations = 0
    limited = np.zeros((n, m), dtype=bool)
    U_flat = U.reshape(-1)
    it_ends = it_aux = pair = item_v = None
    if idx.size:
        item_n, item_v = np.divmod(idx, nV)
        pair = item_n * m + v_poly[item_v]
        payload = np.concatenate([r0x.reshape(1, -1)[:, idx], r0y.reshape(1, -1)[:, idx], per_n[:, item_n]])
        k = idx.size
        flat = (lambda a: a.reshape(2, -1)[:, idx])
        # V'' at the ends is left NaN: only the rare entries the Newton guess
        # does not settle need it, and for them the bracket falls back to the
        # tangent point / midpoint on that side
        s01 = np.broadcast_to(ends[:, :, 0], (2, k))
        start = np.stack([s01, flat(V), flat(V1), np.full((2, k), np.nan)])
        aux = np.stack([flat(zx), flat(zy)], axis=1) if want_lam else None
        # shrink the bracket to the Newton guess: the minimiser lies on the
        # side of s_N where V' changes sign; converged entries then stop in
        # round 0 on the lower-bound test
        s_n = _vertex_newton(*payload)
        s_n = np.where(np.isfinite(s_n) & (s_n > 0) & (s_n < 1), s_n, 0.5)
        g_n, d_n, h_n, zx_n, zy_n = _vertex_curve(s_n, *payload)
        at_n = np.stack([s_n, g_n, d_n, h_n])
        right = d_n < 0                                               # minimiser in [s_N, 1]
        start = np.stack([np.where(right, at_n, start[:, 0]), np.where(right, start[:, 1], at_n)], axis=1)
        if want_lam:
            z_n = np.stack([zx_n, zy_n])
            aux = np.stack([np.where(right, z_n, aux[0]), np.where(right, aux[1], z_n)])
        d0 = p11 * p22 - p12 * p12
        d1 = p11 * w22 + p22 * w11 - 2 * p12 * w12
        d2 = w11 * w22 - w12 * w12
        pole = -2 * d0 / (d1 + np.sqrt(np.maximum(d1 * d1 - 4 * d0 * d2, 0.0)))      # det P(s) = 0
        pole = np.where(np.isfinite(pole) & (pole < 0), pole, -np.inf)[item_n]

        def evaluate(s, data):
            g, d, h, qx, qy = _vertex_curve(s, *data)
            return np.stack([s, g, d, h]), (np.stack([qx, qy], axis=1) if want_lam else None)

        iterations, it_ends, _, it_aux, lim = _minimise_brackets(start, pole, payload, evaluate, tol, max_iter,
                                                                 _decided(threshold), aux)
        np.minimum.at(U_flat, pair, np.minimum(it_ends[1, 0], it_ends[1, 1]))
        limited.reshape(-1)[pair[lim]] = True

    if not (want_s or want_lam):
        return TransitionMinimum(U, None, None, iterations, limited=limited)
    # ---- which feature attains each pair's minimum (first one on ties)
    e_poly = pl.e_poly
    e_arg = np.minimum.reduceat(np.where(e_val <= e_min[:, e_poly], np.arange(E), E), pl.e_start, axis=1)
    v_arg = np.minimum.reduceat(np.where(v_best <= v_min[:, v_poly], np.arange(nV), nV), pl.v_start, axis=1)
    e_arg, v_arg = np.minimum(e_arg, E - 1), np.minimum(v_arg, nV - 1)
    edge_wins = ~inside & (e_min <= v_min)
    vert_wins = ~inside & ~edge_wins & np.isfinite(v_min)
    rows = np.arange(n)[:, None]
    v_end = (V[1] < V[0])[rows, v_arg]
    s_out = np.where(edge_wins, s_e[rows, e_arg], np.where(vert_wins & v_end, 1.0, 0.0))
    won = None
    if idx.size:
        it_best = np.minimum(it_ends[1, 0], it_ends[1, 1])
        won = np.flatnonzero((it_best <= U_flat[pair]) & (it_best < U0.reshape(-1)[pair]))
        s_out.reshape(-1)[pair[won]] = np.where(it_ends[1, 1, won] < it_ends[1, 0, won],
                                                it_ends[0, 1, won], it_ends[0, 0, won])
    lam = None
    if want_lam:
        lam = np.zeros((n, m, ps.A.shape[1]))
        ni, mi = np.nonzero(edge_wins)
        ea = e_arg[ni, mi]
        lam[ni, mi, pl.e_face[ea]] = -mu[ni, ea]                # lam_i = -c/q at the edge's s*
        ni, mi = np.nonzero(vert_wins)
        va = v_arg[ni, mi]
        end = v_end[ni, mi].astype(int)
        z = np.stack([zx[end, ni, va], zy[end, ni, va]])
        # a curve whose interior minimum its tangent bound settled without
        # iterating (threshold mode): the end certificates mixed so that the
        # value is flat in s, >= that tangent bound (iterated ones follow)
        lo_d, hi_d = V1[0, ni, va], V1[1, ni, va]
        mixed = _mix_certificates(lo_d, hi_d, np.stack([zx[0, ni, va], zy[0, ni, va]]),
                                  np.stack([zx[1, ni, va], zy[1, ni, va]]))
        z = np.where((lo_d < 0) & (hi_d > 0), mixed, z)
        _put_vertex_lam(lam, pl, ni, mi, va, z[0], z[1])
        if won is not None and won.size:
            # s* is only bracketed: mix the end certificates so that the
            # mixture's value is flat in s and >= the tangent lower bound
            z = _mix_certificates(it_ends[2, 0, won], it_ends[2, 1, won], it_aux[0][:, won], it_aux[1][:, won])
            pn, pm = np.divmod(pair[won], m)
            lam[pn, pm] = 0.0
            _put_vertex_lam(lam, pl, pn, pm, item_v[won], z[0], z[1])
        lam = np.maximum(lam, 0.0)
    return TransitionMinimum(U, s_out, lam, iterations, limited=limited)


def _put_vertex_lam(lam, pl: _Planar, ni, mi, va, zx, zy) -> None:
    """Lemma-1 certificate of a vertex: c_S = A_S (v - x), G_SS = A_S P A_S^T,
    so lam_S = -G_SS^-1 c_S = -A_S^-T P^-1 (v - x) = -A_S^-T z."""
    B = pl.v_cert[va]
    for k in range(2):
        lam[ni, mi, pl.v_faces[va, k]] = -(B[:, k, 0] * zx + B[:, k, 1] * zy)

