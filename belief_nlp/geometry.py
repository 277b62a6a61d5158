"""Exact safety geometry of confidence ellipses against convex polytopes.

Notation: ellipse E(x, P) = {y : (y-x)^T P^-1 (y-x) <= chi2}; polytope
{y : A y <= b}. With G = A P A^T and c = b - A x, the squared Mahalanobis
distance from x to the polytope is

    dist2 = min_{A y <= b} (y-x)^T P^-1 (y-x) = max_{lam >= 0} -lam^T G lam - 2 lam^T c

(paper Lemma 1; the maximiser ``lam`` is the Lemma-1 certificate).

Transitions (paper Definition 3, Theorem 1 and errata 5): x(s) = x_prev +
s (x_next - x_prev), P(s) = P_prev + s W, s in [0, 1]. dist2(s) is convex
and C1 in s (Theorem 1's minimax argument), and the transition is clear iff
its minimum over [0, 1] is >= chi2. Everything here computes that minimum
exactly (a 1-D convex minimisation to ~1e-10, never sampling s).

Two implementations share the public functions:

* the generic one (any dimension, and 2-D on request via ``_generic``)
  enumerates the faces of each polytope once (:class:`PolytopeSet`): the
  minimiser of Lemma 1 lies in the relative interior of one face; for the
  face with active rows S the candidate value is c_S^T G_SS^-1 c_S, feasible
  iff G_{:,S} G_SS^-1 c_S <= c. Over s it runs a bracketed Newton-type
  iteration on dist2(s) itself;
* the planar one (d = 2, by far the common case for the planner) uses that
  the nearest point of a polygon lies on an edge or is a vertex, and splits
  min_s dist2(s) into per-feature minimisations (see :func:`_planar_transitions`):
  edges in closed form, vertex curves from a Newton guess on their pole form
  (:func:`_vertex_newton`) checked by a convexity lower bound. It is plain
  vectorised arithmetic with no fancy indexing, which is what makes it fast
  for the small batches a planner issues; it also returns minimisers and
  Theorem-1 certificates.

Margins are "clearances": dist2 - chi2 (>= 0 means clear). Containment of an
ellipse in a polytope uses the support function, b - a^T x - sqrt(chi2 a^T P a)
per face (paper Remark 1 / Lemma 3 with errata 2-3).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, Sequence

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

    When more than |S| planes pass through one face (a vertex of a pyramid,
    or nearly coplanar facets of a hull), one active set per face suffices,
    and it must be the best-conditioned one: a set containing two nearly
    parallel planes locates the face badly, and the candidate value then
    misses the true distance (seen: 2e-4 relative on a hull with a 1e-5
    sliver).
    """
    f, d = A.shape
    out: list[list[tuple[tuple[int, ...], bool]]] = [[] for _ in range(d + 1)]
    scale = 1.0 + float(np.max(np.abs(b)))
    An = A / np.linalg.norm(A, axis=1, keepdims=True)
    for k in range(1, min(d, f) + 1):
        best: dict[tuple[int, ...], tuple[float, tuple[int, ...]]] = {}
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
            key = tuple(np.flatnonzero(on))
            sigma = float(np.linalg.svd(An[list(S)], compute_uv=False)[-1])
            if key not in best or sigma > best[key][0]:
                best[key] = (sigma, S)
        out[k].extend((S, k < d) for _, S in best.values())
    return out


def _polygon_features(A: np.ndarray, b: np.ndarray) -> tuple[list, list]:
    """Edges and vertices of the 2-D polytope {A y <= b}, from (A, b) alone.

    Each face i is the line a_i^T y = b_i clipped by the other half-planes to
    an interval of u = t_i^T y, where t_i = rot90(a_i)/|a_i| runs
    counter-clockwise; the interval may be unbounded (half-planes, wedges,
    strips). Faces whose interval is empty or a point are dropped (a point is
    a vertex and is covered by the vertex list). Every vertex is the
    low-u end of exactly one edge, which lists each vertex once without
    deduplication.

    Returns ``edges`` as (a, b_i, t, u_lo, u_hi, face) and ``vertices`` as
    (v, i, j): the point and the two faces meeting there (i: the edge leaving
    v, j: the face that cut it), from which Lemma-1 certificates are built.
    """
    f = A.shape[0]
    tol = 1e-12 * (1.0 + float(np.max(np.abs(b))))
    edges, vertices = [], []
    for i in range(f):
        a = A[i]
        nrm = float(np.hypot(a[0], a[1]))
        t = np.array([-a[1], a[0]]) / nrm
        p = a * (b[i] / nrm**2)
        lo, hi, j_lo, empty = -np.inf, np.inf, -1, False
        for j in range(f):
            if j == i:
                continue
            at = float(A[j] @ t)
            slack = float(b[j] - A[j] @ p)
            if abs(at) <= 1e-12 * float(np.hypot(A[j, 0], A[j, 1])):
                empty |= slack < -tol
                continue
            bound = slack / at
            if at > 0:
                hi = min(hi, bound)
            elif bound > lo:
                lo, j_lo = bound, j
        if empty or not hi - lo > tol:
            continue
        edges.append((a, float(b[i]), t, lo, hi, i))
        if np.isfinite(lo):
            vertices.append((p + lo * t, i, j_lo))
    return edges, vertices


@dataclass(frozen=True, eq=False)
class _Planar:
    """The polygons of a 2-D :class:`PolytopeSet` as flat feature lists.

    Features of all polytopes are concatenated (no padding: a wall has one
    edge and no vertex, an obstacle four of each), per-polytope results come
    from ``np.minimum.reduceat`` over the ``*_start`` offsets. Linear
    functions of the per-transition data are one matrix product with
    ``M_tr`` / ``M_pt`` (see :func:`_planar_transitions`).
    """

    n_edges: int
    f_start: np.ndarray     # (m,) offsets into the flat face list (inside test)
    e_start: np.ndarray     # (m,)
    e_lo: np.ndarray        # (1, E) foot interval in u = t^T y
    e_hi: np.ndarray
    e_face: np.ndarray      # (E,) local face index of each edge
    v_start: np.ndarray     # (m,)
    vx: np.ndarray          # (1, V)
    vy: np.ndarray
    v_pen: np.ndarray       # (1, V) 0, or inf for the placeholder of a vertex-free polytope
    v_faces: np.ndarray     # (V, 2) local faces meeting at the vertex
    v_cert: np.ndarray      # (V, 2, 2) A_S^-T: lam_S = -A_S^-T P^-1 (v - x)
    e_poly: np.ndarray      # (E,) polytope of each edge
    v_poly: np.ndarray      # (V,) polytope of each vertex
    M_tr: np.ndarray        # (13, 8E + F) see _planar_transitions
    M_pt: np.ndarray        # (7, 4E + F) see _planar_points

    @staticmethod
    def build(items: list[tuple[np.ndarray, np.ndarray]]) -> "_Planar":
        E_rows, V_rows, F_rows = [], [], []
        e_start, v_start, f_start = [], [], []
        for A, b in items:
            edges, verts = _polygon_features(A, b)
            e_start.append(len(E_rows))
            v_start.append(len(V_rows))
            f_start.append(len(F_rows))
            F_rows.extend(zip(A, b))
            if not edges:       # empty polytope: an edge that never holds a foot
                edges = [(np.array([1.0, 0.0]), 0.0, np.array([0.0, 1.0]), np.inf, -np.inf, 0)]
            E_rows.extend(edges)
            if verts:
                V_rows.extend((v, i, j, 0.0, A) for v, i, j in verts)
            else:               # reduceat needs a member: a placeholder never chosen
                V_rows.append((np.zeros(2), 0, 0, np.inf, None))
        a = np.array([e[0] for e in E_rows])
        eb = np.array([e[1] for e in E_rows])
        t = np.array([e[2] for e in E_rows])
        ax, ay, tx, ty = a[:, 0], a[:, 1], t[:, 0], t[:, 1]
        fa = np.array([r[0] for r in F_rows])
        fb = np.array([r[1] for r in F_rows])
        E, F = len(E_rows), len(F_rows)
        z = np.zeros(E)
        # Coefficients of the linear forms in the rows of the data matrix
        # [1, x, y, dx, dy, vec(P0), vec(W)] of _planar_transitions: one
        # matrix product gives every per-edge quantity. Quadratic forms use
        # all four entries of vec(P), which symmetrises P for free, and the
        # covariance floor enters through the constant row.
        quad = np.stack([ax * ax, ax * ay, ay * ax, ay * ay])       # a^T P a
        cross = np.stack([tx * ax, tx * ay, ty * ax, ty * ay])      # t^T P a
        Z4 = np.zeros((4, E))
        lin = lambda c1, cx, cy, cdx, cdy: np.stack([c1, cx, cy, cdx, cdy])  # noqa: E731
        cols_tr = [
            np.vstack([lin(eb, -ax, -ay, z, z), Z4, Z4]),           # alpha = c(0) = b - a^T x0
            np.vstack([lin(z, z, z, -ax, -ay), Z4, Z4]),            # beta = dc/ds
            np.vstack([lin(z, tx, ty, z, z), Z4, Z4]),              # t^T x0
            np.vstack([lin(z, z, z, tx, ty), Z4, Z4]),              # t^T dx
            np.vstack([lin(_P_FLOOR * (ax * ax + ay * ay), z, z, z, z), quad, Z4]),   # q0 = a^T P0 a
            np.vstack([lin(z, z, z, z, z), Z4, quad]),              # q1 = a^T W a
            np.vstack([lin(z, z, z, z, z), cross, Z4]),             # t^T P0 a
            np.vstack([lin(z, z, z, z, z), Z4, cross]),             # t^T W a
            np.vstack([fb[None], -fa.T, np.zeros((10, F))]),        # faces: b - A x0
        ]
        M_tr = np.hstack(cols_tr)
        M_pt = M_tr[[0, 1, 2, 5, 6, 7, 8]][:, np.r_[0:E, 2 * E:3 * E, 4 * E:5 * E, 6 * E:7 * E, 8 * E:8 * E + F]]
        v_cert = np.zeros((len(V_rows), 2, 2))
        for k, (_, i, j, pen, A) in enumerate(V_rows):
            if A is not None:
                v_cert[k] = np.linalg.inv(A[[i, j]]).T
        return _Planar(
            n_edges=E,
            f_start=np.array(f_start), e_start=np.array(e_start),
            e_lo=np.array([e[3] for e in E_rows])[None], e_hi=np.array([e[4] for e in E_rows])[None],
            e_face=np.array([e[5] for e in E_rows]),
            v_start=np.array(v_start),
            vx=np.array([r[0][0] for r in V_rows])[None], vy=np.array([r[0][1] for r in V_rows])[None],
            v_pen=np.array([r[3] for r in V_rows])[None],
            v_faces=np.array([[r[1], r[2]] for r in V_rows]),
            v_cert=v_cert,
            e_poly=np.repeat(np.arange(len(items)), np.diff(np.append(e_start, E))),
            v_poly=np.repeat(np.arange(len(items)), np.diff(np.append(v_start, len(V_rows)))),
            M_tr=np.ascontiguousarray(M_tr), M_pt=np.ascontiguousarray(M_pt),
        )


@dataclass(frozen=True)
class PolytopeSet:
    """Several polytopes packed for batched distance queries.

    Faces are padded to a common count with the inert row 0^T y <= 1, and
    the candidate active sets of each size k are padded with a mask.
    Build once (e.g. per scenario) and reuse: it is the expensive part.
    In 2-D the set also carries the flat edge/vertex lists of the planar
    fast path.
    """

    A: np.ndarray            # (m, F, d)
    b: np.ndarray            # (m, F)
    n_faces: np.ndarray      # (m,)
    cand: tuple              # per k = 1..d: (idx (m, C_k, k), valid (m, C_k), check (m, C_k))
    names: tuple[str, ...]
    scale: float
    planar: _Planar | None = None

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
        planar = _Planar.build([(A, b) for A, b, _ in items]) if d == 2 else None
        return cls(A_pad, b_pad, nf, tuple(cand), tuple(names), scale, planar)

    @property
    def dim(self) -> int:
        return int(self.A.shape[2])

    def __len__(self) -> int:
        return int(self.A.shape[0])


# --------------------------------------------------------------------------
# generic (any dimension) evaluation
# --------------------------------------------------------------------------
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
    for k, (idx_all, mask_all, check_all) in enumerate(ps.cand, start=1):
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


def _quiet(fn: Callable) -> Callable:
    """Run ``fn`` with float warnings off: the vectorised code evaluates
    every branch of its case splits (0/0, inf - inf in unused lanes) and
    selects afterwards. One context per public call is also much cheaper
    than one per helper call."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return fn(*args, **kwargs)
    return wrapper


def _batch(x, P):
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    single = x.ndim == 1
    return np.atleast_2d(x), (P[None] if P.ndim == 2 else P), single


# --------------------------------------------------------------------------
# bracketed 1-D convex minimisation (shared by both paths)
# --------------------------------------------------------------------------
def _rational_step(d: np.ndarray, h: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Offset to the minimiser of m(s) = A/(s - s_p) + B + C s fitted to g', g''.

    dist2 along a transition behaves like this model: an ellipse vertex term
    |r(s)|^2 / (p + s w) has exactly this form with the pole s_p = -p/w where
    P(s) turns singular. Plain Newton (the tau -> inf limit, to which this
    reduces) crawls on such functions when P_prev is tiny -- steps grow by
    x1.5 per iteration near the pole -- while this step is exact for them.
    ``tau = s - s_p > 0``; NaN when the model has no minimum (caller falls back).
    Written as -2 d / (h sq (1 + sq)) to stay accurate for tau -> inf.
    """
    sq = np.sqrt(1.0 + 2.0 * d / (h * tau))
    return -2.0 * d / (h * sq * (1.0 + sq))


def _minimise_brackets(ends: np.ndarray, pole: np.ndarray, payload: np.ndarray, evaluate: Callable,
                       tol: float, max_iter: int, stop: Callable | None = None,
                       aux: np.ndarray | None = None) -> tuple[int, np.ndarray, np.ndarray, np.ndarray | None]:
    """Vectorised safeguarded minimisation of k convex C1 functions on brackets.

    ``ends`` (4, 2, k): rows s, g, g', g'' at the bracket ends (lo, hi), with
    g'(lo) < 0 < g'(hi), so the minimiser is inside and the best value seen
    is always min(g(lo), g(hi)) (convexity). Each round proposes two points
    -- the rational step (:func:`_rational_step`) from each end, falling back
    to the tangent intersection / midpoint when a step leaves the bracket --
    evaluated together in one batched call (for small batches the cost is
    the number of numpy calls, not their size), and keeps the sub-bracket
    where g' changes sign. The end tangents give a rigorous lower bound LB,
    which is the stopping test: best - LB <= tol (1 + |best|).

    ``evaluate(s (2, k'), payload (..., k'))`` returns ((4, 2, k') like
    ``ends``, aux at the points (2, r, k') or None); ``payload`` is the
    per-entry data, compressed here as entries retire. ``stop(pos, best, lb)``
    may retire entries early (threshold decisions, pruning); ``pos`` are the
    original entry indices. ``aux`` (2, r, k) rides along with the ends.
    Returns (rounds, final ends, final LB, final aux), in the original order.
    """
    k = ends.shape[2]
    out_ends = np.empty_like(ends)
    out_lb = np.empty(k)
    out_aux = None if aux is None else np.empty_like(aux)
    pos = np.arange(k)
    it = 0
    while True:
        s, g, d = ends[0], ends[1], ends[2]
        t = np.minimum(np.maximum((g[1] - g[0] + d[0] * s[0] - d[1] * s[1]) / (d[0] - d[1]), s[0]), s[1])
        lb = g[0] + d[0] * (t - s[0])
        best = np.minimum(g[0], g[1])
        done = (best - lb <= tol * (1.0 + np.abs(best))) | (s[1] - s[0] <= 1e-15)
        if stop is not None:
            done |= stop(pos, best, lb)
        if it >= max_iter:
            done[:] = True
        if done.any():
            p = pos[done]
            out_ends[:, :, p] = ends[:, :, done]
            out_lb[p] = lb[done]
            if aux is not None:
                out_aux[:, :, p] = aux[:, :, done]
            keep = ~done
            if not keep.any():
                return it, out_ends, out_lb, out_aux
            pos, ends, pole, t = pos[keep], ends[:, :, keep], pole[keep], t[keep]
            payload = payload[..., keep]
            if aux is not None:
                aux = aux[:, :, keep]
            s = ends[0]
        it += 1
        cand = s + _rational_step(ends[2], ends[3], s - pole)
        fallback = np.stack([t, 0.5 * (s[0] + s[1])])
        cand = np.sort(np.where((cand > s[0]) & (cand < s[1]), cand, fallback), axis=0)
        pts, paux = evaluate(cand, payload)
        left = pts[2, 0] >= 0                     # minimiser in [lo, p0]
        mid = ~left & (pts[2, 1] >= 0)            # in [p0, p1]; else in [p1, hi]
        lo_new = np.where(left, ends[:, 0], np.where(mid, pts[:, 0], pts[:, 1]))
        hi_new = np.where(left, pts[:, 0], np.where(mid, pts[:, 1], ends[:, 1]))
        ends = np.stack([lo_new, hi_new], axis=1)
        if aux is not None:
            aux = np.stack([np.where(left, aux[0], np.where(mid, paux[0], paux[1])),
                            np.where(left, paux[0], np.where(mid, paux[1], aux[1]))])


def _decided(threshold: float | None) -> Callable | None:
    """Early stop for :func:`_minimise_brackets` in threshold mode: an entry
    is decided once some value is below the threshold or its lower bound is
    above it."""
    if threshold is None:
        return None
    return lambda pos, best, lb: (best < threshold) | (lb >= threshold)


def _left_pole(P0: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Largest root s_p < 0 of det(P0 + s W) per transition (-inf if none).

    It is where P(s) of Definition 3 would turn singular, the pole that makes
    dist2(s) steep near s = 0 when P_prev is small; see :func:`_rational_step`.
    """
    try:
        L = np.linalg.cholesky(P0)
        Li = np.linalg.inv(L)
        lam = np.linalg.eigvalsh(Li @ W @ np.swapaxes(Li, -1, -2))[..., -1]
    except np.linalg.LinAlgError:
        return np.full(P0.shape[0], -np.inf)
    with np.errstate(divide="ignore"):
        return np.where(lam > 0, -1.0 / lam, -np.inf)


# --------------------------------------------------------------------------
# planar fast path
# --------------------------------------------------------------------------
# OpenBLAS runs a GEMM multithreaded once M*N*K exceeds 4 * 65536. The
# planar products have K = 7 or 13, so threading buys nothing, and on a
# shared machine waking the threads cost up to 10x (measured: 16 ms vs 1.1 ms
# for 1000 ellipses x 10 polygons on 2 busy cores). Stay under the threshold.
_GEMM_BUDGET = 200_000


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
    return P[:, 0, 0] + floor, 0.5 * (P[:, 0, 1] + P[:, 1, 0]), P[:, 1, 1] + floor


def _planar_points(pl: _Planar, x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """dist2 (n, m) of points x (n, 2) under P (n, 2, 2) to every polygon.

    Outside a convex polygon the nearest point (in the P^-1 metric) is on the
    boundary: either the foot on an edge's line, when it falls inside the
    edge, with value (a^T x - b)^2 / (a^T P a) (paper Remark 1), or a vertex v
    with (v-x)^T P^-1 (v-x). Every such candidate is a point of the polygon,
    so the minimum over all of them is exact; inside, dist2 = 0.
    """
    n = x.shape[0]
    R = _small_k_matmul(np.concatenate([np.ones((n, 1)), x, P.reshape(n, 4)], axis=1), pl.M_pt)
    E = pl.n_edges
    c, tx, q, tpa = R[:, :E], R[:, E:2 * E], R[:, 2 * E:3 * E], R[:, 3 * E:4 * E]
    mu = c / q
    u = tx + tpa * mu                       # foot y* = x + P a mu, in edge coordinates
    ev = np.where((u >= pl.e_lo) & (u <= pl.e_hi), c * mu, np.inf)
    p11, p12, p22 = (v[:, None] for v in _sym_entries(P))
    rx = pl.vx - x[:, :1]
    ry = pl.vy - x[:, 1:]
    vv = (p22 * rx * rx - 2 * p12 * rx * ry + p11 * ry * ry) / (p11 * p22 - p12 * p12) + pl.v_pen
    d2 = np.minimum(np.minimum.reduceat(ev, pl.e_start, axis=1), np.minimum.reduceat(vv, pl.v_start, axis=1))
    d2[np.minimum.reduceat(R[:, 4 * E:], pl.f_start, axis=1) >= 0] = 0.0      # mean inside
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


@dataclass
class _PlanarResult:
    dist2: np.ndarray            # (n, m)
    s: np.ndarray | None         # (n, m)
    lam: np.ndarray | None       # (n, m, F)
    iterations: int


def _planar_transitions(ps: PolytopeSet, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, W: np.ndarray,
                        tol: float, max_iter: int, threshold: float | None,
                        want_s: bool, want_lam: bool) -> _PlanarResult:
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

        iterations, it_ends, _, it_aux = _minimise_brackets(start, pole, payload, evaluate, tol, max_iter,
                                                            _decided(threshold), aux)
        np.minimum.at(U_flat, pair, np.minimum(it_ends[1, 0], it_ends[1, 1]))

    if not (want_s or want_lam):
        return _PlanarResult(U, None, None, iterations)
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
        _put_vertex_lam(lam, pl, ni, mi, va, zx[end, ni, va], zy[end, ni, va])
        if won is not None and won.size:
            # s* is only bracketed: mix the end certificates so that the
            # mixture's value is flat in s and >= the tangent lower bound
            d_lo, d_hi = it_ends[2, 0, won], it_ends[2, 1, won]
            theta = np.clip(np.nan_to_num(d_hi / (d_hi - d_lo)), 0.0, 1.0)
            z = theta * it_aux[0][:, won] + (1 - theta) * it_aux[1][:, won]
            pn, pm = np.divmod(pair[won], m)
            lam[pn, pm] = 0.0
            _put_vertex_lam(lam, pl, pn, pm, item_v[won], z[0], z[1])
        lam = np.maximum(lam, 0.0)
    return _PlanarResult(U, s_out, lam, iterations)


def _put_vertex_lam(lam, pl: _Planar, ni, mi, va, zx, zy) -> None:
    """Lemma-1 certificate of a vertex: c_S = A_S (v - x), G_SS = A_S P A_S^T,
    so lam_S = -G_SS^-1 c_S = -A_S^-T P^-1 (v - x) = -A_S^-T z."""
    B = pl.v_cert[va]
    for k in range(2):
        lam[ni, mi, pl.v_faces[va, k]] = -(B[:, k, 0] * zx + B[:, k, 1] * zy)


# --------------------------------------------------------------------------
# ellipses
# --------------------------------------------------------------------------
@_quiet
def squared_mahalanobis_distance(x, P, polytopes) -> np.ndarray:
    """min over y in each polytope of (y-x)^T P^-1 (y-x); (n, m) for x (n, d)."""
    ps = _as_set(polytopes)
    xb, Pb, _ = _batch(x, P)
    if ps.planar is not None:
        return _planar_points(ps.planar, xb, np.broadcast_to(Pb, (xb.shape[0], 2, 2)))
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


@_quiet
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
    iterations: int      # bracketing rounds (planar: 0 when closed forms and Newton guesses settle all)


@_quiet
def transition_minimiser(x_prev, P_prev, x_next, W, polytopes, tol: float = 1e-10,
                         max_iter: int = 60, want_lam: bool = False,
                         threshold: float | None = None, _generic: bool = False) -> TransitionMinimum:
    """Minimise dist2(x(s), P(s)) over s in [0, 1] for every transition/polytope pair.

    x(s) = x_prev + s (x_next - x_prev), P(s) = P_prev + s W. The function
    is convex in s, so the tangents at the ends of a bracket give a lower
    bound LB; a pair is converged when best - LB <= tol * (1 + best).
    2-D polygons use the planar path (closed-form edges, see
    :func:`_planar_transitions`), other dimensions a bracketed iteration on
    dist2(s) itself (:func:`_minimise_brackets`).

    With ``threshold`` set, a pair also stops as soon as it is decided
    against it (some g(s) < threshold, or LB >= threshold); ``dist2`` is
    then exact only for the pairs that did not stop early, but always on the
    correct side of ``threshold``.
    """
    ps = _as_set(polytopes)
    x0, P0, _ = _batch(x_prev, P_prev)
    x1 = np.atleast_2d(np.asarray(x_next, float))
    W = np.asarray(W, float)
    W = np.broadcast_to(W, P0.shape) if W.ndim == 2 else W
    if ps.planar is not None and not _generic:
        r = _planar_transitions(ps, x0, P0, x1, W, tol, max_iter, threshold, True, want_lam)
        return TransitionMinimum(r.dist2, r.s, r.lam, r.iterations)
    return _generic_transitions(ps, x0, P0, x1, W, tol, max_iter, want_lam, threshold)


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

        it, ends, _, aux = _minimise_brackets(start, pole, active, evaluate, tol, max_iter, _decided(threshold), aux)
        best[active] = np.minimum(ends[1, 0], ends[1, 1])
        best_s[active] = np.where(ends[1, 1] < ends[1, 0], ends[0, 1], ends[0, 0])
        if want_lam:
            # Mix the certificates on both sides of the minimiser so that the
            # mixture's value is flat in s (Theorem 1's common lambda); its
            # value is then >= the tangent lower bound.
            dl, dh = ends[2, 0], ends[2, 1]
            theta = np.clip(np.nan_to_num(dh / (dh - dl)), 0.0, 1.0)
            lam[active] = (theta * aux[0] + (1 - theta) * aux[1]).T
    if want_lam:
        lam = np.maximum(lam, 0.0).reshape(n, m, F)
    return TransitionMinimum(best.reshape(n, m), best_s.reshape(n, m), lam, it)


@_quiet
def _min_dist2(x_prev, P_prev, x_next, W, polytopes, threshold: float | None) -> np.ndarray:
    """min_s dist2 (n, m) without minimisers or certificates (the planner's
    hot path); with ``threshold``, exact only where that decides nothing."""
    ps = _as_set(polytopes)
    if ps.planar is None:
        return transition_minimiser(x_prev, P_prev, x_next, W, ps, threshold=threshold).dist2
    x0, P0, _ = _batch(x_prev, P_prev)
    W = np.asarray(W, float)
    W = np.broadcast_to(W, P0.shape) if W.ndim == 2 else W
    return _planar_transitions(ps, x0, P0, np.atleast_2d(np.asarray(x_next, float)), W,
                               1e-10, 60, threshold, False, False).dist2


def transition_clearances(x_prev, P_prev, x_next, W, polytopes, chi2: float) -> np.ndarray:
    """Batched :func:`transition_clearance`: n transitions vs m polytopes -> (n, m).

    ``x_prev``, ``x_next`` (n, d); ``P_prev`` (n, d, d); ``W`` (d, d) shared
    or (n, d, d) per transition.
    """
    return _min_dist2(x_prev, P_prev, x_next, W, polytopes, None) - chi2


def transitions_clear(x_prev, P_prev, x_next, W, polytopes, chi2: float, margin: float = 0.0) -> np.ndarray:
    """Boolean (n, m): is each transition clear of each polytope with
    dist2 >= chi2 + margin for all s? Exact decision (same maths as
    :func:`transition_clearances`) but stops each pair as soon as it is decided,
    which is what a planner needs."""
    thr = chi2 + margin
    return _min_dist2(x_prev, P_prev, x_next, W, polytopes, thr) >= thr


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
