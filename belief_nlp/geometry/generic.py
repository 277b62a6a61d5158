"""The generic path: exact dist2 in any dimension by face enumeration.

Lemma 1 (paper): with c = b - A x and G = A P A^T, the minimiser of
(y-x)^T P^-1 (y-x) over the polytope lies in the relative interior of one of
its faces. For the face with active rows S the candidate value is
c_S^T G_SS^-1 c_S, feasible iff G_{:,S} G_SS^-1 c_S <= c, and lam_S =
-G_SS^-1 c_S is the Lemma-1 certificate. :class:`~.polytopes.PolytopeSet`
enumerates the candidate sets S once; :func:`_evaluate` checks them all for
a batch of (ellipse, polytope) pairs, with s-derivatives along a transition.

Over s, :func:`_generic_transitions` runs the bracketed iteration of
:mod:`.minimise` on dist2(s) itself, each evaluation a full enumeration.
Any dimension, and 2-D on request (``transition_minimiser(..., _generic=True)``),
which is how the tests cross-check the planar path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._numeric import _P_FLOOR
from .minimise import TransitionMinimum, _decided, _left_pole, _minimise_brackets, _mix_certificates
from .polytopes import PolytopeSet


def _solve_small(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve M z = r for stacks of k x k systems (k <= 3 in closed form)."""
    k = M.shape[-1]
    if k == 1:
        return r / M[..., 0, :]
    if k == 2:
        a, b_, c, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
        det = a * d - b_ * c
        z0 = (d * r[..., 0] - b_ * r[..., 1]) / det
        z1 = (a * r[..., 1] - c * r[..., 0]) / det
        return np.stack([z0, z1], axis=-1)
    # padded / degenerate candidate sets are singular: give them nan (masked
    # out as infeasible) instead of letting LAPACK raise
    ok = np.abs(np.linalg.det(M)) > 1e-300
    out = np.linalg.solve(np.where(ok[..., None, None], M, np.eye(k)), r[..., None])[..., 0]
    return np.where(ok[..., None], out, np.nan)


@dataclass
class _Eval:
    g: np.ndarray        # dist2 at the query            (N,)
    g1: np.ndarray       # d dist2 / ds                   (N,)
    g2: np.ndarray       # d^2 dist2 / ds^2 (one-sided)   (N,)
    lam: np.ndarray      # Lemma-1 maximiser              (N, F)


def _evaluate(c: np.ndarray, G: np.ndarray, midx: np.ndarray, ps: PolytopeSet,
              dc: np.ndarray | None = None, dG: np.ndarray | None = None,
              want_lam: bool = False) -> _Eval:
    """dist2 for N (ellipse, polytope) pairs, and s-derivatives when
    dc = dc/ds and dG = dG/ds are given.

    c (N, F) = b - A x,  G (N, F, F) = A P A^T,  midx (N,) polytope index.
    """
    N, F = c.shape
    tol = 1e-9 * (np.max(np.abs(c), axis=-1) + ps.scale)
    best = np.where(np.all(c >= 0, axis=-1), 0.0, np.inf)  # inside: distance 0
    g1 = np.zeros(N)
    g2 = np.zeros(N)
    lam = np.zeros((N, F)) if want_lam else None
    rows = np.arange(N)
    for k, (idx_all, mask_all, check_all, sign_all) in enumerate(ps.cand, start=1):
        idx = idx_all[midx]                                   # (N, C, k)
        mask = mask_all[midx]                                 # (N, C)
        n_ar = rows[:, None, None]
        cS = c[n_ar, idx]                                     # (N, C, k)
        GS = G[n_ar[..., None], idx[..., :, None], idx[..., None, :]]   # (N, C, k, k)
        mu = _solve_small(GS, cS)
        # ||u||^2 of the candidate point u = B_S^T mu itself (B = A L), whose
        # feasibility is checked below: = c_S^T mu in exact arithmetic, but on
        # ill-conditioned faces (slivers) c_S^T mu can even come out negative,
        # while mu^T G_SS mu is always the distance of a real point
        val = np.einsum("nck,nckl,ncl->nc", mu, GS, mu)
        ok = mask & np.isfinite(val)
        if k > 1:
            # Faces cut by (nearly) parallel planes -- slivers of a hull -- make
            # G_SS numerically singular and mu meaningless. A meaningful solve
            # has c_S^T mu = mu^T G_SS mu >= 0; drop candidates where the two
            # disagree (the sliver's points stay within its width of the
            # single-plane candidates, which remain).
            c_mu = np.einsum("nck,nck->nc", cS, mu)
            ok &= (val >= 0) & (np.abs(c_mu - val) <= 1e-7 * (1.0 + np.abs(val)))
        if np.any(sign_all):
            # an extra subset of a degenerate face counts only with lam_S >= 0
            # (its value equals the face's; its certificate must be valid)
            lam_ok = np.all(mu <= 1e-9 * np.max(np.abs(mu), axis=-1, keepdims=True), axis=-1)
            ok &= lam_ok | ~sign_all[midx]
        if np.any(check_all):
            GcS = G[n_ar[..., None], np.arange(F)[None, None, :, None], idx[:, :, None, :]]  # (N, C, F, k)
            resid = np.einsum("ncfk,nck->ncf", GcS, mu) - c[:, None, :]
            ok &= np.all(resid <= tol[:, None, None], axis=-1) | ~check_all[midx]
        val = np.where(ok, val, np.inf)
        j = np.argmin(val, axis=-1)
        vbest = val[rows, j]
        better = vbest < best
        if not np.any(better):
            continue
        best = np.where(better, vbest, best)
        mu_b = mu[rows, j]                                    # (N, k)
        idx_b = idx[rows, j]                                  # (N, k)
        if dc is not None:
            r_ar = rows[:, None]
            dcS = dc[r_ar, idx_b]
            GSb = G[r_ar[..., None], idx_b[:, :, None], idx_b[:, None, :]]
            dGS = dG[r_ar[..., None], idx_b[:, :, None], idx_b[:, None, :]]
            # g = c^T G^-1 c:  g' = 2 c'^T mu - mu^T G' mu,  g'' = 2 r^T G^-1 r, r = c' - G' mu
            r = dcS - np.einsum("nij,nj->ni", dGS, mu_b)
            d1 = 2 * np.einsum("ni,ni->n", dcS, mu_b) - np.einsum("ni,nij,nj->n", mu_b, dGS, mu_b)
            d2 = 2 * np.einsum("ni,ni->n", r, _solve_small(GSb, r))
            g1 = np.where(better, d1, g1)
            g2 = np.where(better, d2, g2)
        if want_lam:
            lam_k = np.zeros((N, F))
            lam_k[rows[:, None], idx_b] = -mu_b               # lam_S = -G_SS^-1 c_S >= 0
            lam = np.where(better[:, None], lam_k, lam)
    return _Eval(best, g1, g2, lam)


def _prepare(x: np.ndarray, P: np.ndarray, ps: PolytopeSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat pair data for ellipses (n, d) against all m polytopes.

    Returns c = b - A x (n*m, F), G = A P A^T (n*m, F, F) and the polytope
    index of each pair (n*m,), pairs ordered ellipse-major.
    """
    n, m = x.shape[0], len(ps)
    c = ps.b[None] - np.einsum("mfd,nd->nmf", ps.A, x)
    P = P + _P_FLOOR * np.eye(P.shape[-1])
    AP = np.einsum("mfd,nde->nmfe", ps.A, P)
    G = np.einsum("nmfe,mge->nmfg", AP, ps.A)
    F = ps.A.shape[1]
    midx = np.tile(np.arange(m), n)
    return c.reshape(n * m, F), G.reshape(n * m, F, F), midx


def _generic_transitions(ps, x0, P0, x1, W, tol, max_iter, want_lam, threshold) -> TransitionMinimum:
    """Any dimension: :func:`_minimise_brackets` on dist2(s) itself, each
    evaluation a full Lemma-1 face enumeration (:func:`_evaluate`)."""
    n, m = x0.shape[0], len(ps)
    N = n * m
    c0, G0, midx = _prepare(x0, P0, ps)
    F = c0.shape[1]
    dc = -np.einsum("mfd,nd->nmf", ps.A, x1 - x0).reshape(N, F)            # dc/ds
    AW = np.einsum("mfd,nde->nmfe", ps.A, W)
    dG = np.einsum("nmfe,mge->nmfg", AW, ps.A).reshape(N, F, F)             # dG/ds

    def at(s: np.ndarray, sel: np.ndarray) -> _Eval:
        return _evaluate(c0[sel] + s[:, None] * dc[sel], G0[sel] + s[:, None, None] * dG[sel],
                         midx[sel], ps, dc[sel], dG[sel], want_lam)

    both = np.arange(N)
    e = at(np.concatenate([np.zeros(N), np.ones(N)]), np.concatenate([both, both]))
    g_lo, g_hi = e.g[:N], e.g[N:]
    d_lo, d_hi = e.g1[:N], e.g1[N:]
    best = np.minimum(g_lo, g_hi)
    best_s = np.where(g_hi < g_lo, 1.0, 0.0)
    lam = None
    if want_lam:
        lam = np.where((g_hi < g_lo)[:, None], e.lam[N:], e.lam[:N])
    # an interior minimum only where the slope changes sign inside (0, 1)
    open_ = (d_lo < 0) & (d_hi > 0) & np.isfinite(best) & (best > 0)
    if threshold is not None:
        open_ &= best >= threshold
    active = np.nonzero(open_)[0]
    it = 0
    limited = np.zeros(N, dtype=bool)
    if active.size:
        k = active.size
        pole = np.repeat(_left_pole(P0 + _P_FLOOR * np.eye(P0.shape[-1]), W), m)[active]
        start = np.stack([np.stack([np.zeros(k), np.ones(k)]),
                          np.stack([g_lo[active], g_hi[active]]), np.stack([d_lo[active], d_hi[active]]),
                          np.stack([e.g2[:N][active], e.g2[N:][active]])])
        aux = np.stack([e.lam[:N][active].T, e.lam[N:][active].T]) if want_lam else None

        def evaluate(s, sel):
            ev = at(s.reshape(-1), np.concatenate([sel, sel]))
            shape = (2, sel.size)
            pts = np.stack([s, ev.g.reshape(shape), ev.g1.reshape(shape), ev.g2.reshape(shape)])
            return pts, (np.swapaxes(ev.lam.reshape(2, sel.size, F), 1, 2) if want_lam else None)

        it, ends, _, aux, lim = _minimise_brackets(start, pole, active, evaluate, tol, max_iter, _decided(threshold),
                                                   aux)
        limited[active] = lim
        # convexity keeps the bracket's ends below [0, 1]'s; where rounding
        # broke a slope's sign (needle covariances) the better end stays
        it_best = np.minimum(ends[1, 0], ends[1, 1])
        kept = it_best < best[active]
        best[active] = np.where(kept, it_best, best[active])
        best_s[active] = np.where(kept, np.where(ends[1, 1] < ends[1, 0], ends[0, 1], ends[0, 0]),
                                  best_s[active])
        if want_lam:
            lam[active] = np.where(kept[:, None], _mix_certificates(ends[2, 0], ends[2, 1], aux[0], aux[1]).T,
                                   lam[active])
    if want_lam:
        lam = np.maximum(lam, 0.0).reshape(n, m, F)
    return TransitionMinimum(best.reshape(n, m), best_s.reshape(n, m), lam, it, limited=limited.reshape(n, m))
