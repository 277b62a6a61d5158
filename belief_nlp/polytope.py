"""Convex polytopes in half-space form {y : A y <= b} with unit normals.

A :class:`Polytope` is immutable. It can be built from a 2-D vertex list (either
orientation), from 3-D vertices (convex hull), from a box, or from half-spaces.
Bounded polytopes also carry their vertices (2-D: counter-clockwise order),
which plotting and the independent verifier use.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import ValidationError

__all__ = ["Polytope"]

# Relative tolerance used for geometric predicates (collinearity, vertex
# feasibility). Scenarios are O(1) m in size; 1e-9 of that is far below any
# physical meaning and far above float rounding.
_REL_TOL = 1e-9


def _as_finite_array(value: Any, field_name: str, ndim: int) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValidationError(field_name, f"must be numeric, got {value!r}") from exc
    if arr.ndim != ndim:
        raise ValidationError(field_name, f"must be a {ndim}-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(field_name, "contains NaN or infinite values")
    return arr


def _normalise_rows(A: np.ndarray, b: np.ndarray, field_name: str) -> tuple[np.ndarray, np.ndarray]:
    norms = np.linalg.norm(A, axis=1)
    if np.any(norms <= 1e-12):
        bad = int(np.argmin(norms))
        raise ValidationError(f"{field_name}.A", f"row {bad} is a zero normal")
    # Rows already of unit length are left bit-for-bit alone so that save/load
    # round-trips exactly.
    scale = np.where(np.abs(norms - 1.0) <= 4e-16, 1.0, norms)
    return A / scale[:, None], b / scale


def _polygon_from_vertices(V: np.ndarray, field_name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate a convex polygon and return (A, b, vertices in CCW order)."""
    n = V.shape[0]
    if n < 3:
        raise ValidationError(field_name, f"a polygon needs at least 3 vertices, got {n}")
    span = float(np.max(np.ptp(V, axis=0)))
    if span <= 0:
        raise ValidationError(field_name, "degenerate polygon: all vertices coincide")
    edges = np.roll(V, -1, axis=0) - V
    lengths = np.linalg.norm(edges, axis=1)
    if np.any(lengths <= _REL_TOL * span):
        i = int(np.argmin(lengths))
        raise ValidationError(field_name, f"degenerate polygon: vertices {i} and {(i + 1) % n} coincide")
    area2 = float(np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1]))
    if abs(area2) <= _REL_TOL * span * span:
        raise ValidationError(field_name, "degenerate polygon: zero area (collinear vertices)")
    if area2 < 0:  # clockwise input: reverse to counter-clockwise
        V = V[::-1].copy()
        edges = np.roll(V, -1, axis=0) - V
        lengths = np.linalg.norm(edges, axis=1)
    cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    turn_tol = _REL_TOL * span * span
    if np.any(np.abs(cross) <= turn_tol):
        i = int(np.argmin(np.abs(cross)))
        raise ValidationError(field_name, f"degenerate polygon: vertex {(i + 1) % n} is collinear with its neighbours")
    if np.any(cross < 0):
        i = int(np.argmin(cross))
        raise ValidationError(field_name, f"polygon is not convex (reflex turn at vertex {(i + 1) % n})")
    # All left turns can still wind more than once (a pentagram): the heading
    # must turn through exactly 2*pi.
    angles = np.arctan2(cross, np.sum(edges * np.roll(edges, -1, axis=0), axis=1))
    if abs(float(np.sum(angles)) - 2 * np.pi) > 1e-6:
        raise ValidationError(field_name, "polygon is self-intersecting (it winds more than once)")
    # Outward normal of CCW edge (ex, ey) is (ey, -ex).
    A = np.column_stack([edges[:, 1], -edges[:, 0]]) / lengths[:, None]
    b = np.einsum("ij,ij->i", A, V)
    return A, b, V


def _vertex_enumeration(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Vertices of {A y <= b} by brute-force enumeration of d-subsets of faces."""
    f, d = A.shape
    scale = 1.0 + float(np.max(np.abs(b)))
    verts = []
    for S in itertools.combinations(range(f), d):
        AS = A[list(S)]
        if abs(np.linalg.det(AS)) < 1e-12:
            continue
        v = np.linalg.solve(AS, b[list(S)])
        if np.all(A @ v <= b + _REL_TOL * scale):
            verts.append(v)
    if not verts:
        return np.zeros((0, d))
    V = np.array(verts)
    # deduplicate (several subsets meet at a degenerate vertex)
    keep: list[np.ndarray] = []
    for v in V:
        if not any(np.linalg.norm(v - w) <= _REL_TOL * scale for w in keep):
            keep.append(v)
    return np.array(keep)


def _order_ccw(V: np.ndarray) -> np.ndarray:
    c = V.mean(axis=0)
    ang = np.arctan2(V[:, 1] - c[1], V[:, 0] - c[0])
    return V[np.argsort(ang)]


@dataclass(frozen=True, eq=False)
class Polytope:
    """A convex polytope {y in R^d : A y <= b} with unit-length rows of A.

    Use the constructors :meth:`from_vertices`, :meth:`box` or
    :meth:`from_halfspaces`; they validate their input and raise
    :class:`~belief_nlp.errors.ValidationError` naming ``field`` on faults.

    Attributes
    ----------
    A, b:
        Half-space form, ``A`` of shape (f, d) with unit rows, ``b`` of shape (f,).
    vertices:
        (n, d) vertices for bounded polytopes (counter-clockwise in 2-D),
        ``None`` for unbounded ones (e.g. a single half-space).
    name:
        Optional label used in reports ("obstacle 3", "wall 2").
    """

    A: np.ndarray
    b: np.ndarray
    vertices: np.ndarray | None = None
    name: str = ""
    spec: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ ctors
    @classmethod
    def from_vertices(cls, vertices: Any, name: str = "", field_name: str = "vertices") -> "Polytope":
        """Convex hull of the given vertices.

        In 2-D the vertices must already form a convex polygon (either
        orientation); non-convex, self-intersecting or degenerate lists are
        rejected. In 3-D and above the convex hull is taken and every given
        vertex must be a hull vertex.
        """
        V = _as_finite_array(vertices, field_name, 2)
        d = V.shape[1]
        if d < 2:
            raise ValidationError(field_name, f"vertices must have dimension >= 2, got {d}")
        if d == 2:
            A, b, Vccw = _polygon_from_vertices(V, field_name)
            return cls(A, b, Vccw, name, {"vertices": V.tolist()})
        return cls._from_hull(V, name, field_name)

    @classmethod
    def _from_hull(cls, V: np.ndarray, name: str, field_name: str) -> "Polytope":
        from scipy.spatial import ConvexHull, QhullError

        d = V.shape[1]
        if V.shape[0] < d + 1:
            raise ValidationError(field_name, f"a {d}-D polytope needs at least {d + 1} vertices, got {V.shape[0]}")
        try:
            hull = ConvexHull(V)
        except QhullError as exc:
            raise ValidationError(field_name, "degenerate polytope (vertices do not span the space)") from exc
        if len(hull.vertices) != V.shape[0]:
            missing = sorted(set(range(V.shape[0])) - set(hull.vertices.tolist()))
            raise ValidationError(field_name, f"vertices {missing} are not extreme points: the list is not a convex polytope")
        eq = hull.equations  # (facets, d+1): n.y + off <= 0, unit normals
        A_list: list[np.ndarray] = []
        b_list: list[float] = []
        for row in eq:
            n, off = row[:-1], -row[-1]
            if not any(np.allclose(n, a, atol=1e-9) and abs(off - bb) < 1e-9 for a, bb in zip(A_list, b_list)):
                A_list.append(n)
                b_list.append(off)
        A, b = _normalise_rows(np.array(A_list), np.array(b_list), field_name)
        return cls(A, b, V[np.sort(hull.vertices)], name, {"vertices": V.tolist()})

    @classmethod
    def box(cls, lower: Any, upper: Any, name: str = "", field_name: str = "box") -> "Polytope":
        """Axis-aligned box ``lower <= y <= upper``."""
        lo = _as_finite_array(lower, f"{field_name}.lower", 1)
        hi = _as_finite_array(upper, f"{field_name}.upper", 1)
        if lo.shape != hi.shape:
            raise ValidationError(field_name, f"lower and upper have different lengths {lo.size} and {hi.size}")
        if lo.size < 2:
            raise ValidationError(field_name, f"dimension must be >= 2, got {lo.size}")
        if np.any(hi - lo <= 0):
            i = int(np.argmin(hi - lo))
            raise ValidationError(field_name, f"degenerate box: upper[{i}] <= lower[{i}]")
        d = lo.size
        A = np.vstack([np.eye(d), -np.eye(d)])
        b = np.concatenate([hi, -lo])
        corners = np.array(list(itertools.product(*zip(lo, hi))))
        V = _order_ccw(corners) if d == 2 else corners
        return cls(A, b, V, name, {"box": {"lower": lo.tolist(), "upper": hi.tolist()}})

    @classmethod
    def from_halfspaces(cls, A: Any, b: Any, name: str = "", field_name: str = "halfspaces",
                        require_bounded: bool = True) -> "Polytope":
        """``{y : A y <= b}``; rows are normalised to unit length."""
        A_arr = _as_finite_array(A, f"{field_name}.A", 2)
        b_arr = _as_finite_array(b, f"{field_name}.b", 1)
        if A_arr.shape[0] != b_arr.shape[0]:
            raise ValidationError(field_name, f"A has {A_arr.shape[0]} rows but b has {b_arr.shape[0]} entries")
        d = A_arr.shape[1]
        if d < 2:
            raise ValidationError(f"{field_name}.A", f"dimension must be >= 2, got {d}")
        A_arr, b_arr = _normalise_rows(A_arr, b_arr, field_name)
        spec = {"A": np.asarray(A, dtype=float).tolist(), "b": np.asarray(b, dtype=float).tolist()}
        if not require_bounded:
            return cls(A_arr, b_arr, None, name, spec)
        if A_arr.shape[0] < d + 1:
            raise ValidationError(field_name, f"a bounded {d}-D polytope needs at least {d + 1} half-spaces, got {A_arr.shape[0]}")
        V = _vertex_enumeration(A_arr, b_arr)
        if V.shape[0] < d + 1:
            raise ValidationError(field_name, "empty, degenerate or unbounded polytope")
        # bounded iff no direction y with A y <= 0 other than 0: check via
        # the vertex hull -- every face must touch at least d vertices and the
        # hull must have interior.
        from scipy.optimize import linprog

        for i in range(d):
            for sgn in (1.0, -1.0):
                c = np.zeros(d)
                c[i] = -sgn
                res = linprog(c, A_ub=A_arr, b_ub=b_arr, bounds=[(None, None)] * d, method="highs")
                if res.status == 3:
                    raise ValidationError(field_name, "unbounded polytope")
        centre = V.mean(axis=0)
        if np.max(A_arr @ centre - b_arr) >= -_REL_TOL * (1 + np.max(np.abs(b_arr))):
            raise ValidationError(field_name, "degenerate polytope (no interior)")
        if d == 2:
            V = _order_ccw(V)
        return cls(A_arr, b_arr, V, name, spec)

    @classmethod
    def halfspace(cls, a: Any, beta: float, name: str = "") -> "Polytope":
        """The single half-space ``{y : a^T y <= beta}`` (unbounded)."""
        return cls.from_halfspaces(np.atleast_2d(np.asarray(a, dtype=float)), [beta], name=name,
                                   require_bounded=False)

    # ------------------------------------------------------------- properties
    @property
    def dim(self) -> int:
        return int(self.A.shape[1])

    @property
    def n_faces(self) -> int:
        return int(self.A.shape[0])

    @property
    def bounded(self) -> bool:
        return self.vertices is not None

    def contains(self, y: Any, tol: float = 0.0) -> np.ndarray | bool:
        """Whether point(s) ``y`` (..., d) satisfy ``A y <= b + tol``."""
        y = np.asarray(y, dtype=float)
        out = np.all(y @ self.A.T <= self.b + tol, axis=-1)
        return bool(out) if out.ndim == 0 else out

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        if self.vertices is None:
            raise ValueError("unbounded polytope has no bounding box")
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def complement_halfspaces(self, prefix: str) -> list["Polytope"]:
        """The faces of this polytope turned outward: ``{y : a_i^T y >= b_i}``.

        The outside of a convex polytope is the union of these half-spaces
        (paper, section II.C: X_out^l and X_tout^n).
        """
        return [Polytope(-self.A[i:i + 1].copy(), -self.b[i:i + 1].copy(), None, f"{prefix} {i}",
                         {"A": (-self.A[i:i + 1]).tolist(), "b": (-self.b[i:i + 1]).tolist()})
                for i in range(self.n_faces)]

    def to_dict(self) -> dict:
        """Serialisable form; reproduces this polytope exactly via :meth:`from_dict`."""
        out = dict(self.spec) if self.spec else {"A": self.A.tolist(), "b": self.b.tolist()}
        if self.name:
            out = {"name": self.name, **out}
        return out

    @classmethod
    def from_dict(cls, data: Any, field_name: str = "polytope", require_bounded: bool = True) -> "Polytope":
        """Build from ``{"vertices": ...}``, ``{"box": {"lower", "upper"}}`` or ``{"A", "b"}``."""
        if not isinstance(data, dict):
            raise ValidationError(field_name, f"must be a table/object, got {type(data).__name__}")
        name = data.get("name", "")
        if not isinstance(name, str):
            raise ValidationError(f"{field_name}.name", "must be a string")
        keys = {k for k in ("vertices", "box", "A") if k in data}
        if len(keys) != 1:
            raise ValidationError(field_name, "give exactly one of 'vertices', 'box' or 'A'/'b'")
        unknown = set(data) - {"name", "vertices", "box", "A", "b"}
        if unknown:
            raise ValidationError(field_name, f"unknown keys {sorted(unknown)}")
        if "vertices" in data:
            return cls.from_vertices(data["vertices"], name, f"{field_name}.vertices")
        if "box" in data:
            box = data["box"]
            if not isinstance(box, dict) or set(box) != {"lower", "upper"}:
                raise ValidationError(f"{field_name}.box", "must have exactly the keys 'lower' and 'upper'")
            return cls.box(box["lower"], box["upper"], name, f"{field_name}.box")
        if "b" not in data:
            raise ValidationError(field_name, "'A' given without 'b'")
        return cls.from_halfspaces(data["A"], data["b"], name, field_name, require_bounded)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Polytope):
            return NotImplemented
        return (self.name == other.name and self.A.shape == other.A.shape
                and bool(np.array_equal(self.A, other.A)) and bool(np.array_equal(self.b, other.b)))

    def __hash__(self) -> int:
        return hash((self.name, self.A.tobytes(), self.b.tobytes()))

    def __repr__(self) -> str:
        label = f" {self.name!r}" if self.name else ""
        return f"Polytope{label}(dim={self.dim}, faces={self.n_faces})"
