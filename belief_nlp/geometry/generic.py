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


def _solve_small(M: np.ndarray, r: np.ndarray, BS: np.ndarray | None = None) -> np.ndarray:
    """Solve M z = r for stacks of k x k systems (k <= 3 in closed form).

    ``BS`` (..., k, d), when given, are the whitened normals with M = BS BS^T
    (a Gram matrix, k <= d). Two nearly (anti-)parallel planes -- a hull's
    sliver -- make M's determinant cancel to ~eps cond(M) relative when formed
    from M, and mu then misses the face (a valid but useless certificate,
    lower bound 0 against a true 2e8, seen in 3-D); from BS the determinant
    of k = 2 is the Lagrange identity's sum of squared 2x2 minors, and k = d
    solves through BS itself: rounding ~eps sqrt(cond(M)) instead.
    """
    k = M.shape[-1]
    if k == 1:
        return r / M[..., 0, :]
    if BS is not None and k == BS.shape[-1] and k <= 3:
        adj, det = _adjugate(BS)
        inv = adj / det[..., None, None]
        out = np.einsum("...ji,...j->...i", inv, np.einsum("...ij,...j->...i", inv, r))   # B^-T B^-1 r
        return np.where((np.abs(det) > 1e-300)[..., None], out, np.nan)
    if k == 2:
        adj, det = _adjugate(M)
        if BS is not None:                    # the Gram determinant of BS's two rows, without cancellation
            u, v = BS[..., 0, :], BS[..., 1, :]
            det = sum((u[..., i] * v[..., j] - u[..., j] * v[..., i]) ** 2
                      for i in range(u.shape[-1]) for j in range(i + 1, u.shape[-1]))
        return np.einsum("...ij,...j->...i", adj, r) / det[..., None]
    # padded / degenerate candidate sets are singular: give them nan (masked
    # out as infeasible) instead of letting LAPACK raise
    ok = np.abs(np.linalg.det(M)) > 1e-300
    out = np.linalg.solve(np.where(ok[..., None, None], M, np.eye(k)), r[..., None])[..., 0]
    return np.where(ok[..., None], out, np.nan)


def _adjugate(B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(adj B, det B) for stacks of 2 x 2 or 3 x 3 matrices, in closed form
    (rows b_i: the 3 x 3 adjugate's columns are b_1 x b_2, b_2 x b_0,
    b_0 x b_1), so B^-1 = adj / det. A singular entry gives inf / nan there,
    masked by the caller -- LAPACK would raise for the whole stack."""
    if B.shape[-1] == 2:
        a, b_, c, d = B[..., 0, 0], B[..., 0, 1], B[..., 1, 0], B[..., 1, 1]
        return np.stack([np.stack([d, -b_], -1), np.stack([-c, a], -1)], -2), a * d - b_ * c
    r0, r1, r2 = B[..., 0, :], B[..., 1, :], B[..., 2, :]
    adj = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], -1)
    return adj, np.einsum("...i,...i->...", r0, adj[..., 0])


def _feasible(c: np.ndarray, G: np.ndarray, idx: np.ndarray, mu: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """Is each candidate point of a face (N, C) inside the other planes, to
    ``tol`` (N,) plus rounding?

    The residual G_{:,S} mu - c rounds to ~eps |G| |mu| (3e-8 seen on a
    sliver's edge, mu ~ 1e10), so that is added to the slack. The rows of S
    hold by construction (G_SS mu = c_S) up to that rounding and are not
    tested: testing them dropped the minimiser's edge.
    """
    N, F = c.shape
    n_ar = np.arange(N)[:, None, None]
    GcS = G[n_ar[..., None], np.arange(F)[None, None, :, None], idx[:, :, None, :]]  # (N, C, F, k)
    resid = np.einsum("ncfk,nck->ncf", GcS, mu) - c[:, None, :]
    slack = tol[:, None, None] + 16 * np.finfo(float).eps * np.einsum("ncfk,nck->ncf", np.abs(GcS), np.abs(mu))
    in_S = np.zeros(resid.shape, dtype=bool)
    np.put_along_axis(in_S, idx, True, axis=-1)
    return np.all((resid <= slack) | in_S, axis=-1)


def _outside(c: np.ndarray, B: np.ndarray, u: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """Does each whitened point u (N, d) lie outside some plane, by more than
    ``tol`` (N,) plus the rounding of B u - c? (N,)

    B u - c is the residual of a real point, accurate to ~eps (|B| |u| + |c|)
    however large the mu that made u was.
    """
    resid = np.einsum("nfd,nd->nf", B, u) - c
    slack = tol[:, None] + 4 * (B.shape[-1] + 1) * np.finfo(float).eps * (
        np.einsum("nfd,nd->nf", np.abs(B), np.abs(u)) + np.abs(c))
    return np.any(resid > slack, axis=-1)


def _vertex_checked(vals: np.ndarray, c: np.ndarray, B: np.ndarray, u: np.ndarray, vertex: np.ndarray,
                    tol: np.ndarray) -> np.ndarray:
    """``vals`` (N, C) with each pair's nearest vertex candidate dropped (inf)
    until the point computed for it (u (N, C, d)) passes :func:`_outside`;
    ``vertex`` (N, C) marks the candidates no other test covers."""
    rows = np.arange(vals.shape[0])
    while rows.size:
        j = np.argmin(vals[rows], axis=-1)
        bad = vertex[rows, j] & np.isfinite(vals[rows, j]) & _outside(c[rows], B[rows], u[rows, j], tol[rows])
        vals[rows[bad], j[bad]] = np.inf
        rows = rows[bad]
    return vals


@dataclass
class _Eval:
    g: np.ndarray        # dist2 at the query            (N,)
    g1: np.ndarray       # d dist2 / ds                   (N,)
    g2: np.ndarray       # d^2 dist2 / ds^2 (one-sided)   (N,)
    lam: np.ndarray      # Lemma-1 maximiser              (N, F)


def _evaluate(c: np.ndarray, G: np.ndarray, midx: np.ndarray, ps: PolytopeSet,
              dc: np.ndarray | None = None, dG: np.ndarray | None = None,
              want_lam: bool = False, B: np.ndarray | None = None, strict: bool = False) -> _Eval:
    """dist2 for N (ellipse, polytope) pairs, and s-derivatives when
    dc = dc/ds and dG = dG/ds are given.

    c (N, F) = b - A x,  G (N, F, F) = A P A^T,  midx (N,) polytope index;
    B (N, F, d) = A L with L L^T = P, when given, for the face solves
    (:func:`_solve_small`).

    The nearest feasible candidate gives the value, and its certificate and
    s-derivatives come with it. Where that is in doubt -- a sliver's vertex
    (two near-parallel planes) solves to mu of +-1e9..1e11, which gives a
    certificate with a negative entry (lower bound 0), wrong slopes (the
    minimisation over s stopped 2.9e-6 above the minimum), and a computed
    point off the vertex and outside the hull (a value 1.2e-7 *below* the
    minimum) -- those pairs are evaluated again ``strict``ly: every vertex's
    computed point must pass :func:`_outside`, and the certificate and the
    slopes come from the candidate of the largest dual value
    2 c_S^T mu - ||u||^2 among those with lam_S = -mu >= 0 (each bounds
    dist2 from below, feasible or not; Danskin: dist2' is the s-derivative
    of the dual function at its maximiser). At a regular minimiser both
    rules pick the same candidate.
    """
    N, F = c.shape
    tol = 1e-9 * (np.max(np.abs(c), axis=-1) + ps.scale)
    best = np.where(np.all(c >= 0, axis=-1), 0.0, np.inf)  # inside: distance 0
    dual = np.zeros(N)                                    # lam = 0 proves dist2 >= 0
    doubt = np.zeros(N, dtype=bool)
    dual_wanted = dc is not None or want_lam
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
        BS = None if B is None else B[n_ar, idx]              # (N, C, k, d)
        mu = _solve_small(GS, cS, BS)
        # ||u||^2 of the candidate point u = B_S^T mu itself (B = A L), whose
        # feasibility is checked below: = c_S^T mu in exact arithmetic, but on
        # ill-conditioned faces (slivers) c_S^T mu can even come out negative,
        # while ||u||^2 is always the distance of a real point. Formed from u
        # when B is given: mu^T G_SS mu cancels to ~eps |mu|^T |G_SS| |mu|
        # at a sliver's sharp vertex (2.5e-6 relative seen), ||u||^2 does not
        if BS is None:
            val = np.einsum("nck,nckl,ncl->nc", mu, GS, mu)
        else:
            u = np.einsum("nckd,nck->ncd", BS, mu)
            val = np.einsum("ncd,ncd->nc", u, u)
        ok = mask & np.isfinite(val)
        c_mu = val
        if k > 1:
            # Faces cut by (nearly) parallel planes -- slivers of a hull -- make
            # G_SS numerically singular and mu meaningless. A meaningful solve
            # has c_S^T mu = mu^T G_SS mu >= 0; drop candidates where the two
            # disagree (the sliver's points stay within its width of the
            # single-plane candidates, which remain).
            c_mu = np.einsum("nck,nck->nc", cS, mu)
            ok &= (val >= 0) & (np.abs(c_mu - val) <= 1e-7 * (1.0 + np.abs(val)))
        if strict or np.any(sign_all):
            lam_ok = _nonpositive(mu)                         # lam_S = -mu >= 0
        if np.any(sign_all):
            # an extra subset of a degenerate face counts only with lam_S >= 0
            # (its value equals the face's; its certificate must be valid)
            ok &= lam_ok | ~sign_all[midx]
        if strict:
            dual_ok = ok & lam_ok                             # feasible point or not
        if np.any(check_all):
            ok &= _feasible(c, G, idx, mu, tol) | ~check_all[midx]
        vals = np.where(ok, val, np.inf)
        vertex = BS is not None and k == BS.shape[-1]
        if strict:
            if vertex:
                vals = _vertex_checked(vals, c, B, u, ~check_all[midx], tol)
            best = np.minimum(best, np.min(vals, axis=-1))
            if not dual_wanted:
                continue
            q = np.where(dual_ok, 2 * c_mu - val, -np.inf)
            j = np.argmax(q, axis=-1)
            better = q[rows, j] > dual
            dual = np.where(better, q[rows, j], dual)
        else:
            j = np.argmin(vals, axis=-1)
            better = vals[rows, j] < best
            best = np.where(better, vals[rows, j], best)
            bad = ~_nonpositive(mu[rows, j]) if dual_wanted else np.zeros(N, dtype=bool)
            if vertex:
                r = np.flatnonzero(better & ~check_all[midx, j])
                bad[r] |= _outside(c[r], B[r], u[r, j[r]], tol[r])
            doubt = np.where(better, bad, doubt)
        if not np.any(better):
            continue
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
            d2 = 2 * np.einsum("ni,ni->n", r, _solve_small(GSb, r, None if B is None else B[r_ar, idx_b]))
            g1 = np.where(better, d1, g1)
            g2 = np.where(better, d2, g2)
        if want_lam:
            lam_k = np.zeros((N, F))
            lam_k[rows[:, None], idx_b] = -mu_b               # lam_S = -G_SS^-1 c_S >= 0
            lam = np.where(better[:, None], lam_k, lam)
    if doubt.any():
        r = np.flatnonzero(doubt)
        e = _evaluate(c[r], G[r], midx[r], ps, None if dc is None else dc[r], None if dG is None else dG[r],
                      want_lam, None if B is None else B[r], strict=True)
        best[r], g1[r], g2[r] = e.g, e.g1, e.g2
        if want_lam:
            lam[r] = e.lam
    return _Eval(best, g1, g2, lam)


def _nonpositive(mu: np.ndarray) -> np.ndarray:
    """mu (..., k) <= 1e-9 max |mu| entry-wise, i.e. lam_S = -mu >= 0 up to rounding. (...)"""
    hi = mu.max(axis=-1)
    return hi <= 1e-9 * np.maximum(hi, -mu.min(axis=-1))


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


def _whitened(P: np.ndarray, ps: PolytopeSet) -> np.ndarray | None:
    """B = A L (n*m, F, d) with L L^T = P (+ the floor), pairs ordered as in
    :func:`_prepare`; None where a covariance is not numerically positive
    definite (the face solves then use G alone)."""
    try:
        L = np.linalg.cholesky(P + _P_FLOOR * np.eye(P.shape[-1]))
    except np.linalg.LinAlgError:
        return None
    B = np.einsum("mfd,nde->nmfe", ps.A, L)
    return B.reshape(-1, *B.shape[2:])


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
        t = sel // m                                          # pairs are transition-major
        B = _whitened(P0[t] + s[:, None, None] * W[t], ps)
        if B is not None:                                     # each pair's own polytope: rows j * m + midx
            B = B.reshape(sel.size, m, *B.shape[1:])[np.arange(sel.size), midx[sel]]
        return _evaluate(c0[sel] + s[:, None] * dc[sel], G0[sel] + s[:, None, None] * dG[sel],
                         midx[sel], ps, dc[sel], dG[sel], want_lam, B)

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
