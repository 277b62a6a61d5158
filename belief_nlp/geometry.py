"""Exact safety geometry of confidence ellipses against convex polytopes.

Notation: ellipse E(x, P) = {y : (y-x)^T P^-1 (y-x) <= chi2}; polytope
{y : A y <= b}. With G = A P A^T and c = b - A x, the squared Mahalanobis
distance from x to the polytope is

    dist2 = min_{A y <= b} (y-x)^T P^-1 (y-x) = max_{lam >= 0} -lam^T G lam - 2 lam^T c

(paper Lemma 1; the maximiser ``lam`` is the Lemma-1 certificate). The
minimiser lies in the relative interior of one face of the polytope; for the
face with active rows S the candidate value is c_S^T G_SS^-1 c_S, and the
candidate is feasible iff G_{:,S} G_SS^-1 c_S <= c. We enumerate the faces of
each polytope once (:class:`PolytopeSet`) and evaluate every candidate for many
ellipses at once, so all functions here are batched and loop-free over
ellipses. Everything is written with G and c only, hence dimension-generic.

Transitions (paper Definition 3, Theorem 1 and errata 5): x(s) = x_prev +
s (x_next - x_prev), P(s) = P_prev + s W, s in [0, 1]. For fixed faces S,
g(s) = c(s)^T G(s)^-1 c(s) is a matrix-fractional function of affine data,
hence convex, and dist2(s) = min over feasible faces -- also convex by
Theorem 1's minimax argument. We minimise it with safeguarded Newton steps
(analytic g' and g'') inside a shrinking bracket: exact to ~1e-12, no sampling.

Margins are "clearances": dist2 - chi2 (>= 0 means clear). Containment of an
ellipse in a polytope uses the support function, b - a^T x - sqrt(chi2 a^T P a)
per face (paper Remark 1 / Lemma 3 with errata 2-3).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

__all__ = [
    "PolytopeSet",
    "squared_mahalanobis_distance",
    "ellipse_clearance",
    "ellipse_clearances",
    "transition_clearance",
    "transition_clearances",
    "transition_minimiser",
    "transitions_clear",
    "containment_margin",
    "containment_margins",
    "ellipse_certificate",
    "transition_certificate",
]

# Tiny isotropic floor added to covariances so that P = 0 (an exact start)
# gives huge-but-finite distances instead of 0/0.
_P_FLOOR = 1e-30


# --------------------------------------------------------------------------
# face enumeration
# --------------------------------------------------------------------------
def _face_sets(A: np.ndarray, b: np.ndarray, vertices: np.ndarray | None) -> list[list[tuple[tuple[int, ...], bool]]]:
    """Active sets S (|S| = 1..d) whose faces can hold the nearest point.

    Returns, per size k, pairs (S, needs_check). For bounded polytopes only
    genuine faces are kept (the face with active set S is the set of vertices
    on all planes of S; it is genuine when those vertices span dimension
    d - |S|), and vertex sets (|S| = d) need no feasibility test, which makes
    them immune to rounding. Without vertices (unbounded polytopes, raw A, b)
    every independent subset is kept and checked (correct, just slower).
    """
    f, d = A.shape
    out: list[list[tuple[tuple[int, ...], bool]]] = [[] for _ in range(d + 1)]
    scale = 1.0 + float(np.max(np.abs(b)))
    seen_vertices: list[np.ndarray] = []
    for k in range(1, min(d, f) + 1):
        for S in itertools.combinations(range(f), k):
            AS = A[list(S)]
            if np.linalg.matrix_rank(AS, tol=1e-10) < k:
                continue
            if vertices is None:
                out[k].append((S, True))
                continue
            on = np.all(np.abs(vertices @ AS.T - b[list(S)]) <= 1e-9 * scale, axis=1)
            Vs = vertices[on]
            if Vs.shape[0] < d - k + 1:
                continue
            rank = np.linalg.matrix_rank(Vs[1:] - Vs[0], tol=1e-9 * scale) if Vs.shape[0] > 1 else 0
            if rank != d - k:
                continue
            if k == d:
                # one independent d-subset per vertex is enough
                if any(np.allclose(Vs[0], w, atol=1e-9 * scale) for w in seen_vertices):
                    continue
                seen_vertices.append(Vs[0])
            out[k].append((S, k < d))
    return out


@dataclass(frozen=True)
class PolytopeSet:
    """Several polytopes packed for batched distance queries.

    Faces are padded to a common count with the inert row 0^T y <= 1, and
    the candidate active sets of each size k are padded with a mask.
    Build once (e.g. per scenario) and reuse: it is the expensive part.
    """

    A: np.ndarray            # (m, F, d)
    b: np.ndarray            # (m, F)
    n_faces: np.ndarray      # (m,)
    cand: tuple              # per k = 1..d: (idx (m, C_k, k), valid (m, C_k), check (m, C_k))
    names: tuple[str, ...]
    scale: float

    @classmethod
    def build(cls, polytopes: Sequence) -> "PolytopeSet":
        """From a sequence of :class:`~belief_nlp.polytope.Polytope` or (A, b) pairs."""
        items = []
        names = []
        for i, p in enumerate(polytopes):
            if isinstance(p, tuple):
                A, b = np.asarray(p[0], float), np.asarray(p[1], float)
                items.append((A, b, None))
                names.append(f"polytope {i}")
            else:
                items.append((p.A, p.b, p.vertices))
                names.append(p.name or f"polytope {i}")
        if not items:
            raise ValueError("PolytopeSet needs at least one polytope")
        d = items[0][0].shape[1]
        m = len(items)
        F = max(A.shape[0] for A, _, _ in items)
        A_pad = np.zeros((m, F, d))
        b_pad = np.ones((m, F))
        nf = np.zeros(m, dtype=int)
        sets = []
        for i, (A, b, V) in enumerate(items):
            if A.shape[1] != d:
                raise ValueError("all polytopes of a PolytopeSet must have the same dimension")
            A_pad[i, : A.shape[0]] = A
            b_pad[i, : A.shape[0]] = b
            nf[i] = A.shape[0]
            sets.append(_face_sets(A, b, V))
        cand = []
        for k in range(1, d + 1):
            C = max(1, max(len(s[k]) for s in sets))
            idx = np.zeros((m, C, k), dtype=int)
            mask = np.zeros((m, C), dtype=bool)
            check = np.zeros((m, C), dtype=bool)
            for i, s in enumerate(sets):
                for j, (S, needs_check) in enumerate(s[k]):
                    idx[i, j] = S
                    mask[i, j] = True
                    check[i, j] = needs_check
                # padding repeats a harmless index set (masked anyway)
                if s[k]:
                    idx[i, len(s[k]):] = s[k][0][0]
                else:
                    idx[i, :] = np.arange(k) % max(nf[i], 1)
            cand.append((idx, mask, check))
        scale = float(max(1.0, np.max(np.abs(b_pad))))
        return cls(A_pad, b_pad, nf, tuple(cand), tuple(names), scale)

    @property
    def dim(self) -> int:
        return int(self.A.shape[2])

    def __len__(self) -> int:
        return int(self.A.shape[0])


def _solve_small(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve M z = r for stacks of k x k systems (k <= 3 in closed form)."""
    k = M.shape[-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if k == 1:
            return r / M[..., 0, :]
        if k == 2:
            a, b_, c, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
            det = a * d - b_ * c
            z0 = (d * r[..., 0] - b_ * r[..., 1]) / det
            z1 = (a * r[..., 1] - c * r[..., 0]) / det
            return np.stack([z0, z1], axis=-1)
        return np.linalg.solve(M, r[..., None])[..., 0]


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
    d = ps.dim
    rows = np.arange(N)
    for k, (idx_all, mask_all, check_all) in enumerate(ps.cand, start=1):
        idx = idx_all[midx]                                   # (N, C, k)
        mask = mask_all[midx]                                 # (N, C)
        n_ar = rows[:, None, None]
        cS = c[n_ar, idx]                                     # (N, C, k)
        GS = G[n_ar[..., None], idx[..., :, None], idx[..., None, :]]   # (N, C, k, k)
        mu = _solve_small(GS, cS)
        val = np.einsum("nck,nck->nc", cS, mu)
        ok = mask & np.isfinite(val)
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


@lru_cache(maxsize=256)
def _cached_set(A_bytes: bytes, b_bytes: bytes, d: int) -> PolytopeSet:
    A = np.frombuffer(A_bytes).reshape(-1, d)
    return PolytopeSet.build([(A, np.frombuffer(b_bytes))])


def _as_set(A_or_set, b=None) -> PolytopeSet:
    """PolytopeSet from a set, a Polytope, a sequence of Polytopes or raw (A, b)."""
    if isinstance(A_or_set, PolytopeSet):
        return A_or_set
    if b is None:
        if hasattr(A_or_set, "A"):
            return _cached_polytope_set(A_or_set)
        return PolytopeSet.build(list(A_or_set))
    if hasattr(A_or_set, "A"):
        raise TypeError("pass either a Polytope or the arrays A and b, not both")
    A = np.ascontiguousarray(np.atleast_2d(np.asarray(A_or_set, float)))
    b = np.ascontiguousarray(np.atleast_1d(np.asarray(b, float)))
    if A.shape[0] != b.shape[0]:
        raise ValueError(f"A has {A.shape[0]} rows but b has {b.shape[0]} entries")
    return _cached_set(A.tobytes(), b.tobytes(), A.shape[1])


@lru_cache(maxsize=256)
def _cached_polytope_set(p) -> PolytopeSet:
    return PolytopeSet.build([p])


def _batch(x, P):
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    single = x.ndim == 1
    return np.atleast_2d(x), (P[None] if P.ndim == 2 else P), single


# --------------------------------------------------------------------------
# ellipses
# --------------------------------------------------------------------------
def squared_mahalanobis_distance(x, P, polytopes) -> np.ndarray:
    """min over y in each polytope of (y-x)^T P^-1 (y-x); (n, m) for x (n, d)."""
    ps = _as_set(polytopes)
    xb, Pb, _ = _batch(x, P)
    c, G, midx = _prepare(xb, Pb, ps)
    return _evaluate(c, G, midx, ps).g.reshape(xb.shape[0], len(ps))


def ellipse_clearances(x, P, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`ellipse_clearance`: ellipses (n, d), (n, d, d) vs a
    :class:`PolytopeSet` (or list of polytopes) of m members -> (n, m)."""
    return squared_mahalanobis_distance(x, P, polytopes) - chi2


def ellipse_clearance(x, P, A, b, chi2: float):
    """Squared Mahalanobis distance under P from x to {y : A y <= b}, minus chi2.

    ``>= 0`` iff the confidence ellipse E(x, P) does not overlap the
    polytope (paper Lemma 1). ``x`` (d,) or (n, d), ``P`` (d, d) or (n, d, d);
    returns a float for a single ellipse, else an (n,) array. The value is
    ``-chi2`` when x lies inside the polytope.
    """
    xb, Pb, single = _batch(x, P)
    out = ellipse_clearances(xb, Pb, _as_set(A, b), chi2)[:, 0]
    return float(out[0]) if single else out


def ellipse_certificate(x, P, A, b) -> np.ndarray:
    """The Lemma-1 maximiser lam >= 0 (f,) of -lam^T A P A^T lam + 2 lam^T (A x - b).

    Its value equals the squared Mahalanobis distance, so the ellipse is clear
    iff the value is >= chi2. (Zero vector when x is inside the polytope.)
    """
    ps = _as_set(A, b)
    xb, Pb, _ = _batch(x, P)
    c, G, midx = _prepare(xb, Pb, ps)
    lam = _evaluate(c, G, midx, ps, want_lam=True).lam[0, : ps.n_faces[0]]
    return np.maximum(lam, 0.0)


# --------------------------------------------------------------------------
# containment (domain, target)
# --------------------------------------------------------------------------
def containment_margins(x, P, A, b, chi2: float) -> np.ndarray:
    """Per face: b_i - a_i^T x - sqrt(chi2 a_i^T P a_i) (metres); (..., f).

    ``>= 0`` for every face iff E(x, P) lies inside {A y <= b}
    (paper Lemma 3 / eq. final_cond with the corrected signs, errata 2-4).
    """
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    aPa = np.einsum("fi,...ij,fj->...f", A, P, A)
    return b - x @ A.T - np.sqrt(chi2 * np.maximum(aPa, 0.0))


def containment_margin(x, P, A, b, chi2: float):
    """min over faces of :func:`containment_margins`: float for one ellipse."""
    out = np.min(containment_margins(x, P, A, b, chi2), axis=-1)
    return float(out) if np.ndim(out) == 0 else out


# --------------------------------------------------------------------------
# transitions (Theorem 1)
# --------------------------------------------------------------------------
@dataclass
class TransitionMinimum:
    """Result of :func:`transition_minimiser` for n transitions x m polytopes."""

    dist2: np.ndarray    # (n, m) min over s in [0, 1] of the squared distance
    s: np.ndarray        # (n, m) minimiser
    lam: np.ndarray      # (n, m, F) common certificate (Theorem 1), padded faces
    iterations: int


def transition_minimiser(x_prev, P_prev, x_next, W, polytopes, tol: float = 1e-10,
                         max_iter: int = 60, want_lam: bool = False,
                         threshold: float | None = None) -> TransitionMinimum:
    """Minimise dist2(x(s), P(s)) over s in [0, 1] for every transition/polytope pair.

    x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W. The function
    is convex in s, so the tangents at the ends of the current bracket give
    a lower bound LB; steps are Newton steps (analytic g', g'') safeguarded
    by the tangent-intersection point. A pair is converged when
    best - LB <= tol * (1 + best).

    With ``threshold`` set, a pair also stops as soon as it is decided
    against it (some g(s) < threshold, or LB >= threshold); ``dist2`` is
    then exact only for the pairs that did not stop early.
    """
    ps = _as_set(polytopes)
    x0, P0, _ = _batch(x_prev, P_prev)
    x1 = np.atleast_2d(np.asarray(x_next, float))
    W = np.asarray(W, float)
    W = np.broadcast_to(W, P0.shape) if W.ndim == 2 else W
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
    g_lo, g_hi = e.g[:N].copy(), e.g[N:].copy()
    glo1, ghi1 = e.g1[:N].copy(), e.g1[N:].copy()
    g2_lo, g2_hi = e.g2[:N], e.g2[N:]
    best_g = np.minimum(g_lo, g_hi)
    best_s = np.where(g_hi < g_lo, 1.0, 0.0)
    lam_lo = e.lam[:N].copy() if want_lam else None
    lam_hi = e.lam[N:].copy() if want_lam else None
    lam = np.where((g_hi < g_lo)[:, None], lam_hi, lam_lo) if want_lam else None
    lo = np.zeros(N)
    hi = np.ones(N)
    # an interior minimum only where the slope changes sign inside (0, 1)
    open_ = (glo1 < 0) & (ghi1 > 0) & np.isfinite(best_g) & (best_g > 0)
    if threshold is not None:
        open_ &= best_g >= threshold
    active = np.nonzero(open_)[0]
    g2lo, g2hi = g2_lo.copy(), g2_hi.copy()
    it = 0
    while active.size and it < max_iter:
        it += 1
        sel = active
        l, h = lo[sel], hi[sel]
        gl, gh, dl, dh = g_lo[sel], g_hi[sel], glo1[sel], ghi1[sel]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            n_lo = l - dl / g2lo[sel]                              # Newton from either end
            n_hi = h - dh / g2hi[sel]
            secant = l - dl * (h - l) / (dh - dl)                   # regula falsi on g'
        margin = 1e-9 * (h - l)
        ok_lo = np.isfinite(n_lo) & (n_lo > l + margin) & (n_lo < h - margin)
        ok_hi = np.isfinite(n_hi) & (n_hi > l + margin) & (n_hi < h - margin)
        prefer_lo = np.abs(dl) <= np.abs(dh)
        s_new = np.where(ok_lo & (prefer_lo | ~ok_hi), n_lo, np.where(ok_hi, n_hi, secant))
        # every few steps, or when nothing sensible is left, halve the bracket
        bad = ~np.isfinite(s_new) | (s_new <= l + margin) | (s_new >= h - margin) | (it % 4 == 0)
        s_new = np.where(bad, 0.5 * (l + h), s_new)
        e = at(s_new, sel)
        improve = e.g < best_g[sel]
        best_g[sel] = np.where(improve, e.g, best_g[sel])
        best_s[sel] = np.where(improve, s_new, best_s[sel])
        neg = e.g1 < 0
        lo[sel] = np.where(neg, s_new, l)
        hi[sel] = np.where(neg, h, s_new)
        g_lo[sel] = np.where(neg, e.g, gl)
        g_hi[sel] = np.where(neg, gh, e.g)
        glo1[sel] = np.where(neg, e.g1, dl)
        ghi1[sel] = np.where(neg, dh, e.g1)
        g2lo[sel] = np.where(neg, e.g2, g2lo[sel])
        g2hi[sel] = np.where(neg, g2hi[sel], e.g2)
        if want_lam:
            lam_lo[sel] = np.where(neg[:, None], e.lam, lam_lo[sel])
            lam_hi[sel] = np.where(neg[:, None], lam_hi[sel], e.lam)
        # convexity lower bound on [lo, hi] from the two tangents
        l, h = lo[sel], hi[sel]
        gl, gh, dl, dh = g_lo[sel], g_hi[sel], glo1[sel], ghi1[sel]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.clip((gh - gl + dl * l - dh * h) / (dl - dh), l, h)
            lb = np.where(np.isfinite(t), gl + dl * (t - l), np.minimum(gl, gh))
        bg = best_g[sel]
        done = (bg - lb <= tol * (1.0 + np.abs(bg))) | (e.g1 == 0) | (h - l <= 1e-15) | (bg <= 0)
        if threshold is not None:
            done |= (bg < threshold) | (lb >= threshold)
        active = sel[~done]
    if want_lam:
        # Where the minimum is interior, mix the certificates on both sides so
        # that the mixture's value is flat in s (Theorem 1's common lambda).
        interior = (best_s > 0) & (best_s < 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.where(interior, ghi1 / (ghi1 - glo1), 0.0)
        theta = np.clip(np.nan_to_num(theta), 0.0, 1.0)
        mixed = theta[:, None] * lam_lo + (1 - theta[:, None]) * lam_hi
        lam = np.where(interior[:, None], mixed, lam)
        lam = np.maximum(lam, 0.0).reshape(n, m, F)
    return TransitionMinimum(best_g.reshape(n, m), best_s.reshape(n, m), lam, it)


def transition_clearances(x_prev, P_prev, x_next, W, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`transition_clearance`: n transitions vs m polytopes -> (n, m).

    ``x_prev``, ``x_next`` (n, d); ``P_prev`` (n, d, d); ``W`` (d, d) shared
    or (n, d, d) per transition.
    """
    return transition_minimiser(x_prev, P_prev, x_next, W, polytopes).dist2 - chi2


def transitions_clear(x_prev, P_prev, x_next, W, polytopes, chi2: float, margin: float = 0.0) -> np.ndarray:
    """Boolean (n, m): is each transition clear of each polytope with
    dist2 >= chi2 + margin for all s? Exact decision (same maths as
    :func:`transition_clearances`) but stops each pair as soon as it is decided,
    which is what a planner needs."""
    thr = chi2 + margin
    tm = transition_minimiser(x_prev, P_prev, x_next, W, polytopes, threshold=thr)
    return tm.dist2 >= thr


def transition_clearance(x_prev, P_prev, x_next, W, A, b, chi2: float):
    """min over s in [0, 1] of ellipse_clearance(x(s), P(s), A, b, chi2).

    x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W (paper Definition
    3). ``>= 0`` iff the whole transition is collision-free (Theorem 1 with the
    corrected eq. tran_col_2, errata 5). Exact (a 1-D convex minimisation),
    not sampled. Float for a single transition, (n,) array when batched.
    """
    x0, P0, single = _batch(x_prev, P_prev)
    out = transition_clearances(x0, P0, np.atleast_2d(np.asarray(x_next, float)), W, _as_set(A, b), chi2)[:, 0]
    return float(out[0]) if single else out


def transition_certificate(x_prev, P_prev, x_next, W, A, b) -> tuple[np.ndarray, float]:
    """A common lam >= 0 for both ends of a transition (Theorem 1) and its value.

    Returns ``(lam, value)`` where value = min(f_0(lam), f_1(lam)) with
    f_s(lam) = -lam^T A P(s) A^T lam + 2 lam^T (A x(s) - b). The transition is
    clear iff value >= chi2 is achievable; this lam attains the optimum
    min_s dist2(s) up to solver tolerance.
    """
    ps = _as_set(A, b)
    tm = transition_minimiser(x_prev, P_prev, x_next, W, ps, want_lam=True)
    f = ps.n_faces[0]
    lam = tm.lam[0, 0, :f]
    A = ps.A[0, :f]
    b = ps.b[0, :f]
    x0 = np.asarray(x_prev, float)
    x1 = np.asarray(x_next, float)
    P0 = np.asarray(P_prev, float)
    P1 = P0 + np.asarray(W, float)
    v = lam @ A
    f0 = -v @ P0 @ v + 2 * lam @ (A @ x0 - b)
    f1 = -v @ P1 @ v + 2 * lam @ (A @ x1 - b)
    return lam, float(min(f0, f1))
