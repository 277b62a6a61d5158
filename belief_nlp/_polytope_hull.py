"""Vertex and hull construction behind :class:`~belief_nlp.polytope.Polytope`:
2-D polygons from vertex lists (orientation, repeated vertices, crossing
edges diagnosed), merged coplanar hull facets, the vertices of a bounded
half-space system and counter-clockwise order. Every failure is a
:class:`~belief_nlp.errors.ValidationError` naming the input field.
"""

from __future__ import annotations

import numpy as np

from ._limits import MAX_COORDINATE, MAX_POLYTOPE_VERTICES
from .errors import ValidationError

# Relative tolerance used for geometric predicates (collinearity, vertex
# feasibility). Scenarios are O(1) m in size; 1e-9 of that is far below any
# physical meaning and far above float rounding.
_REL_TOL = 1e-9


def _check_magnitude(values: np.ndarray, field_name: str, what: str = "coordinates") -> None:
    """Reject coordinates beyond :data:`~belief_nlp._limits.MAX_COORDINATE` (documented limit)."""
    if values.size and float(np.max(np.abs(values))) > MAX_COORDINATE:
        raise ValidationError(field_name, f"{what} must lie within +-{MAX_COORDINATE:g} m, got "
                                          f"{float(np.max(np.abs(values))):.3g}")


def _check_count(n: int, limit: int, field_name: str, what: str) -> None:
    if n > limit:
        raise ValidationError(field_name, f"{n} {what} is more than the limit of {limit}")


def _repeated_vertex(V: np.ndarray, field_name: str) -> None:
    """Reject a vertex list in which two vertices (adjacent or not) coincide.

    A k-d tree makes this O(n log n): the first offending pair (i, j) in
    lexicographic order has i = the smallest index with a neighbour within
    the tolerance (every neighbour of that i has a larger index).
    """
    from scipy.spatial import cKDTree

    span = float(np.max(np.ptp(V, axis=0)))
    if span <= 0:
        raise ValidationError(field_name, "degenerate polytope: all vertices coincide")
    tol = _REL_TOL * span
    tree = cKDTree(V)
    nearest, _ = tree.query(V, k=2)
    close = np.flatnonzero(nearest[:, 1] <= tol)
    if close.size:
        i = int(close[0])
        j = min(k for k in tree.query_ball_point(V[i], tol) if k != i)
        raise ValidationError(field_name, f"repeated vertex: vertices {i} and {j} coincide ({V[i].tolist()})")


def _crossing_edges(V: np.ndarray) -> tuple[int, int] | None:
    """First pair of non-adjacent edges (i, i+1), (j, j+1) of a closed polygon that cross.

    Quadratic in the vertex count, so it only runs to explain why a small
    polygon was rejected (the acceptance test itself is linear).
    """
    n = V.shape[0]
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))      # edges 0 and n-1 share vertex 0
    i, j = i[keep], j[keep]
    p1, p2, q1, q2 = V[i], V[(i + 1) % n], V[j], V[(j + 1) % n]

    def orient(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    d1, d2, d3, d4 = orient(q1, q2, p1), orient(q1, q2, p2), orient(p1, p2, q1), orient(p1, p2, q2)
    hit = (d1 * d2 <= 0) & (d3 * d4 <= 0) & ~((d1 == 0) & (d2 == 0) & (d3 == 0) & (d4 == 0))
    first = np.flatnonzero(hit)
    return (int(i[first[0]]), int(j[first[0]])) if first.size else None


# Polygons up to this size that fail validation are also searched for crossing
# edges, to say which edges cross (quadratic, so not for larger ones).
_DIAGNOSE_MAX = 256


def _polygon_from_vertices(V: np.ndarray, field_name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate a convex polygon and return (A, b, vertices in CCW order).

    Accepted iff, after orienting it counter-clockwise, every vertex turns left
    by more than the tolerance and the turns add up to one full turn: such a
    closed polygon is simple and strictly convex. That test is O(n); only a
    rejected small polygon is searched for crossing edges, for the message.
    """
    n = V.shape[0]
    if n < 3:
        raise ValidationError(field_name, f"a polygon needs at least 3 vertices, got {n}")
    _check_count(n, MAX_POLYTOPE_VERTICES, field_name, "vertices")
    _check_magnitude(V, field_name)
    _repeated_vertex(V, field_name)
    span = float(np.max(np.ptp(V, axis=0)))
    area2 = float(np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1]))
    flat = abs(area2) <= _REL_TOL * span * span
    W = V[::-1].copy() if area2 < 0 else V    # counter-clockwise
    edges = np.roll(W, -1, axis=0) - W
    nxt = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]   # turn at vertex i + 1
    # A vertex is collinear with its neighbours when it lies within 1e-9 of
    # the polygon's extent (plus rounding) of the chord joining them. This is
    # a distance, so fine regular polygons (a 4000-gon of radius 0.1 m: the
    # vertex is 1.2e-7 m off the chord) pass, and it scales with the polygon.
    chord = np.linalg.norm(edges + nxt, axis=1)
    height_tol = _REL_TOL * span + 64 * np.finfo(float).eps * float(np.max(np.abs(V)))
    collinear = np.abs(cross) <= height_tol * chord
    angles = np.arctan2(cross, np.sum(edges * nxt, axis=1))
    winds_once = abs(float(np.sum(angles)) - 2 * np.pi) <= 1e-6
    if not flat and not np.any(collinear) and np.all(cross > 0) and winds_once:
        # Outward normal of CCW edge (ex, ey) is (ey, -ex).
        lengths = np.linalg.norm(edges, axis=1)
        A = np.column_stack([edges[:, 1], -edges[:, 0]]) / lengths[:, None]
        b = np.einsum("ij,ij->i", A, W)
        return A, b, W
    crossing = _crossing_edges(V) if n <= _DIAGNOSE_MAX else None
    if crossing is not None:
        i, j = crossing
        raise ValidationError(field_name, f"polygon is self-intersecting: edge {i}-{(i + 1) % n} meets "
                                          f"edge {j}-{(j + 1) % n} (list the vertices in boundary order)")
    if flat:
        raise ValidationError(field_name, "degenerate polygon: zero area (collinear vertices)")
    if np.any(collinear):
        i = int(np.argmax(collinear))
        raise ValidationError(field_name, f"degenerate polygon: vertex {(i + 1) % n} is collinear with its neighbours")
    if np.any(cross < 0):
        i = int(np.argmin(cross))
        raise ValidationError(field_name, f"polygon is not convex (reflex turn at vertex {(i + 1) % n})")
    # All left turns can still wind more than once (a pentagram).
    raise ValidationError(field_name, "polygon is self-intersecting (it winds more than once)")


def _merge_coplanar(eq: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """Indices of the facets to keep when triangles of one face are merged.

    Qhull triangulates: a square face comes back as two facets with (nearly)
    equal equations. Such triangles are adjacent, so only adjacent facets are
    compared (linear in the facet count) and each connected group keeps its
    first facet.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = eq.shape[0]
    i = np.repeat(np.arange(m), neighbors.shape[1])
    j = neighbors.ravel()
    n_i, n_j = eq[i, :-1], eq[j, :-1]
    same = (np.all(np.abs(n_i - n_j) <= 1e-9 + 1e-5 * np.abs(n_j), axis=1)
            & (np.abs(eq[i, -1] - eq[j, -1]) < 1e-9))
    graph = coo_matrix((np.ones(int(same.sum())), (i[same], j[same])), shape=(m, m))
    _, label = connected_components(graph, directed=False)
    first = np.full(int(label.max()) + 1, m)
    np.minimum.at(first, label, np.arange(m))
    return np.sort(first)


def _halfspace_vertices(A: np.ndarray, b: np.ndarray, inner: np.ndarray, field_name: str) -> np.ndarray:
    """Vertices of the bounded {A y <= b} around the interior point ``inner``.

    Qhull's half-space intersection (the dual convex hull, O(f log f)) finds
    which d faces meet at each vertex; the vertex is then solved from those
    faces directly, as precise as a d x d solve. Coincident vertices (more
    than d faces through a point) are merged.
    """
    from scipy.spatial import HalfspaceIntersection, QhullError

    f, d = A.shape
    try:
        hsi = HalfspaceIntersection(np.column_stack([A, -b]), inner)
    except (QhullError, ValueError) as exc:
        raise ValidationError(field_name, "degenerate polytope: its vertices cannot be computed") from exc
    V = np.array(hsi.intersections, dtype=float)
    faces = np.asarray(hsi.dual_facets, dtype=np.int64)
    if faces.ndim == 2 and faces.shape[1] == d:
        M = A[faces]
        ok = np.abs(np.linalg.det(M)) > 1e-12
        if np.any(ok):
            V[ok] = np.linalg.solve(M[ok], b[faces[ok]][..., None])[..., 0]
    # (Every intersection is feasible by construction: Qhull only returns the
    # vertices of the dual hull, i.e. of the non-redundant faces.)
    scale = 1.0 + float(np.max(np.abs(b)))
    V = V[np.all(np.isfinite(V), axis=1)]
    # merge vertices within the tolerance (a grid of that pitch)
    _, first = np.unique(np.round(V / (_REL_TOL * scale)), axis=0, return_index=True)
    return V[np.sort(first)]


def _order_ccw(V: np.ndarray) -> np.ndarray:
    c = V.mean(axis=0)
    ang = np.arctan2(V[:, 1] - c[1], V[:, 0] - c[0])
    return V[np.argsort(ang, kind="stable")]
