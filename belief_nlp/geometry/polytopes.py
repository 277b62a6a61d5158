"""Polytopes packed for batched queries: :class:`PolytopeSet`.

Building a set enumerates, once, what the distance computations need: the
candidate active sets of Lemma 1 for the generic path (:func:`_face_sets`)
and, in 2-D, the edges and vertices of each polygon as flat lists for the
planar path (:func:`_polygon_features`, :class:`_Planar`). :func:`_as_set`
turns what the public functions accept (a set, a Polytope, a sequence of
Polytopes, raw (A, b)) into a set, cached for single polytopes.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from ._numeric import _P_FLOOR

def _face_sets(A: np.ndarray, b: np.ndarray, vertices: np.ndarray | None) -> list[list[tuple[tuple[int, ...], bool, bool]]]:
    """Active sets S (|S| = 1..d) whose faces can hold the nearest point.

    Returns, per size k, triples (S, needs_check, needs_sign). For bounded
    polytopes only genuine faces are kept (the face with active set S is the
    set of vertices on all planes of S; it is genuine when those vertices
    span dimension d - |S|), and vertex sets (|S| = d) need no feasibility
    test, which makes them immune to rounding. Without vertices (unbounded
    polytopes, raw A, b) every independent subset is kept and checked
    (correct, just slower).

    When more than |S| planes pass through one face (a vertex where four
    facets of a triangulated hull meet, a pyramid's apex, nearly coplanar
    facets), any independent k of them locate the face, so the value is
    the same, but the Lemma-1 certificate lam_S = -G_SS^-1 c_S is >= 0 only
    for the k-subsets whose normal cone holds the direction to the query
    (one exists, by Caratheodory). Such faces keep every independent subset,
    best-conditioned first (a set with two nearly parallel planes locates
    the face badly: 2e-4 relative seen on a hull with a 1e-5 sliver), each
    with ``needs_sign``: a subset counts only where its certificate is >= 0,
    so the winning candidate always carries a valid one.
    """
    f, d = A.shape
    out: list[list[tuple[tuple[int, ...], bool, bool]]] = [[] for _ in range(d + 1)]
    scale = 1.0 + float(np.max(np.abs(b)))
    An = A / np.linalg.norm(A, axis=1, keepdims=True)
    for k in range(1, min(d, f) + 1):
        faces: dict[tuple[int, ...], list[tuple[float, tuple[int, ...]]]] = {}
        for S in itertools.combinations(range(f), k):
            AS = A[list(S)]
            if np.linalg.matrix_rank(AS, tol=1e-10) < k:
                continue
            if vertices is None:
                out[k].append((S, True, False))
                continue
            on = np.all(np.abs(vertices @ AS.T - b[list(S)]) <= 1e-9 * scale, axis=1)
            Vs = vertices[on]
            if Vs.shape[0] < d - k + 1:
                continue
            rank = np.linalg.matrix_rank(Vs[1:] - Vs[0], tol=1e-9 * scale) if Vs.shape[0] > 1 else 0
            # rank > d - k only by rounding: vertices a hair apart (a hull's
            # near-duplicate points) that all lie on the planes within the
            # tolerance; the face is genuine, just thickened (dropping it lost
            # a vertex: 30 % overestimates on a near-flat hull)
            if rank < d - k:
                continue
            key = tuple(np.flatnonzero(on))
            sigma = float(np.linalg.svd(An[list(S)], compute_uv=False)[-1])
            faces.setdefault(key, []).append((sigma, S))
        for subsets in faces.values():
            subsets.sort(key=lambda t: -t[0])
            if k == 1 or len(subsets) == 1:
                out[k].append((subsets[0][1], k < d, False))
            else:
                out[k].extend((S, k < d, True) for _, S in subsets)
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
    cand: tuple              # per k = 1..d: (idx (m, C_k, k), valid, check, sign (m, C_k)); see _face_sets
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
            sign = np.zeros((m, C), dtype=bool)
            for i, s in enumerate(sets):
                for j, (S, needs_check, needs_sign) in enumerate(s[k]):
                    idx[i, j] = S
                    mask[i, j] = True
                    check[i, j] = needs_check
                    sign[i, j] = needs_sign
                # padding repeats a harmless index set (masked anyway)
                if s[k]:
                    idx[i, len(s[k]):] = s[k][0][0]
                else:
                    idx[i, :] = np.arange(k) % max(nf[i], 1)
            cand.append((idx, mask, check, sign))
        scale = float(max(1.0, np.max(np.abs(b_pad))))
        planar = _Planar.build([(A, b) for A, b, _ in items]) if d == 2 else None
        return cls(A_pad, b_pad, nf, tuple(cand), tuple(names), scale, planar)

    @classmethod
    def cached(cls, polytopes: Sequence) -> "PolytopeSet":
        """:meth:`build`, kept for the next call with the same polytopes (by
        content: faces, offsets, vertices, names). The build is the expensive
        part (~10 ms for a 10-polygon map: face sets, vertex certificates) and
        one smoothing call needs the same scenario's set four or five times."""
        key = tuple(_content(p) for p in polytopes)
        hit = _SETS.get(key)
        if hit is None:
            hit = _SETS[key] = cls.build(polytopes)
            _read_only(hit)
            while len(_SETS) > 32:
                _SETS.pop(next(iter(_SETS)))
        return hit

    @property
    def dim(self) -> int:
        """Dimension d of the space."""
        return int(self.A.shape[2])

    def __len__(self) -> int:
        return int(self.A.shape[0])


_SETS: dict = {}     # PolytopeSet.cached: content key -> set, oldest first


def _content(p) -> tuple:
    """A hashable key of a Polytope or an (A, b) pair by content."""
    if isinstance(p, tuple):
        A, b, V, name = np.asarray(p[0], float), np.asarray(p[1], float), None, None
    else:
        A, b, V, name = p.A, p.b, p.vertices, p.name
    arrays = tuple((a.shape, np.ascontiguousarray(a, float).tobytes())
                   for a in (A, b) + ((V,) if V is not None else ()))
    return (type(p) is tuple, name, arrays)


def _read_only(obj) -> None:
    """Every array of a shared set (and of its planar part) read-only: a
    caller that writes into one raises instead of changing the others' set."""
    for v in vars(obj).values():
        if isinstance(v, np.ndarray):
            v.setflags(write=False)
        elif isinstance(v, tuple):
            for a in v:
                for x in (a if isinstance(a, tuple) else (a,)):
                    if isinstance(x, np.ndarray):
                        x.setflags(write=False)
        elif isinstance(v, _Planar):
            _read_only(v)


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
