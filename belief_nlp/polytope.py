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

from ._limits import MAX_COORDINATE, MAX_DIMENSION, MAX_POLYTOPE_FACES, MAX_POLYTOPE_VERTICES
from ._polytope_hull import (_REL_TOL, _check_count, _check_magnitude, _halfspace_vertices, _merge_coplanar, _order_ccw,
                             _polygon_from_vertices, _repeated_vertex)
from .errors import ScenarioFileError, ValidationError

__all__ = ["Polytope"]



def _as_finite_array(value: Any, field_name: str, ndim: int) -> np.ndarray:
    """``value`` as a float array of ``ndim`` dimensions with finite entries.

    Booleans, strings, ``None`` and ragged nested lists are rejected with a
    :class:`ValidationError` naming ``field_name`` (numpy alone would turn
    ``True`` into 1.0 and fail on the others with an unrelated message).
    """
    what = "a number" if ndim == 0 else ("a list of numbers" if ndim == 1 else "a list of lists of numbers")
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValidationError(field_name, f"must be {what} of equal lengths, got {value!r}") from exc
    if raw.dtype == object:
        raise ValidationError(field_name, f"must be {what} (ragged or non-numeric entries), got {value!r}")
    if raw.dtype.kind not in "iuf":
        kind = "booleans" if raw.dtype.kind == "b" else type(value).__name__
        raise ValidationError(field_name, f"must be {what}, got {kind}: {value!r}")
    arr = raw.astype(float)
    if arr.ndim != ndim:
        raise ValidationError(field_name, f"must be {what} ({ndim}-D array), got shape {arr.shape}")
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
    # (A row normalised in floating point has a norm within a few ulps of 1.)
    scale = np.where(np.abs(norms - 1.0) <= 1e-15, 1.0, norms)
    return A / scale[:, None], b / scale


def _frozen(arr: np.ndarray) -> np.ndarray:
    """``arr`` made read-only (the caller passes a private copy)."""
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class Polytope:
    """A convex polytope {y in R^d : A y <= b} with unit-length rows of A.

    Use the constructors :meth:`from_vertices`, :meth:`box` or
    :meth:`from_halfspaces`; they validate their input and raise
    :class:`~belief_nlp.errors.ValidationError` naming ``field`` on faults.

    The direct constructor stores what it is given (read-only copies) after
    refusing non-finite or mis-shaped arrays; it derives nothing.

    Parameters
    ----------
    A : array_like, shape (f, d)
        Half-space normals, one unit-length row per face.
    b : array_like, shape (f,)
        Half-space offsets: the polytope is ``A y <= b``.
    vertices : array_like, shape (n, d), optional
        Vertices of a bounded polytope (counter-clockwise in 2-D); None for
        unbounded ones (e.g. a single half-space).
    name : str, optional
        Label used in reports ("obstacle 3", "wall 2").
    spec : dict, optional
        The form the polytope was given in (``{"vertices": ...}``,
        ``{"box": ...}`` or ``{"A", "b"}``), which :meth:`to_dict` writes back.

    Raises
    ------
    ValidationError
        For non-finite or mis-shaped arrays, a dimension above the limit, or
        a name that is not a string.
    """

    A: np.ndarray
    b: np.ndarray
    vertices: np.ndarray | None = None
    name: str = ""
    spec: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        # The direct constructor does not re-derive anything (the classmethods
        # validate geometry), but it still refuses non-finite or mis-shaped
        # arrays, and stores private read-only copies so that no caller can
        # change a polytope a scenario has validated.
        label = self.name or "polytope"
        A = _as_finite_array(self.A, f"{label}.A", 2)
        b = _as_finite_array(self.b, f"{label}.b", 1)
        if A.shape[0] != b.shape[0]:
            raise ValidationError(f"{label}.b", f"A has {A.shape[0]} rows but b has {b.shape[0]} entries")
        if A.shape[1] > MAX_DIMENSION:
            raise ValidationError(f"{label}.A", f"dimension {A.shape[1]} is more than the limit of {MAX_DIMENSION}")
        object.__setattr__(self, "A", _frozen(A))
        object.__setattr__(self, "b", _frozen(b))
        if self.vertices is not None:
            V = _as_finite_array(self.vertices, f"{label}.vertices", 2)
            if V.shape[1] != A.shape[1]:
                raise ValidationError(f"{label}.vertices", f"are {V.shape[1]}-D but A is {A.shape[1]}-D")
            object.__setattr__(self, "vertices", _frozen(V))
        if not isinstance(self.name, str):
            raise ValidationError("name", f"must be a string, got {type(self.name).__name__}")
        if not isinstance(self.spec, dict):
            raise ValidationError(f"{label}.spec", f"must be a dict, got {type(self.spec).__name__}")

    # ------------------------------------------------------------------ ctors
    @classmethod
    def from_vertices(cls, vertices: Any, name: str = "", field_name: str = "vertices") -> "Polytope":
        """Convex hull of the given vertices.

        In 2-D the vertices must already form a convex polygon (either
        orientation); non-convex, self-intersecting or degenerate lists are
        rejected. In 3-D and above the convex hull is taken and every given
        vertex must be a hull vertex. At most
        :data:`~belief_nlp._limits.MAX_POLYTOPE_VERTICES` vertices, each
        coordinate within +-:data:`~belief_nlp._limits.MAX_COORDINATE` m.
        """
        V = _as_finite_array(vertices, field_name, 2)
        d = V.shape[1]
        if d < 2:
            raise ValidationError(field_name, f"vertices must have dimension >= 2, got {d}")
        if d > MAX_DIMENSION:
            raise ValidationError(field_name, f"dimension {d} is more than the limit of {MAX_DIMENSION}")
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
        _check_count(V.shape[0], MAX_POLYTOPE_VERTICES, field_name, "vertices")
        _check_magnitude(V, field_name)
        _repeated_vertex(V, field_name)
        try:
            hull = ConvexHull(V)
        except (QhullError, ValueError) as exc:
            raise ValidationError(field_name, "degenerate polytope (vertices do not span the space)") from exc
        if len(hull.vertices) != V.shape[0]:
            missing = sorted(set(range(V.shape[0])) - set(hull.vertices.tolist()))
            shown = ", ".join(map(str, missing[:10])) + (f", ... ({len(missing)} in all)" if len(missing) > 10 else "")
            raise ValidationError(field_name, f"vertices [{shown}] are not extreme points: the list is not a "
                                              f"convex polytope")
        eq = hull.equations[_merge_coplanar(hull.equations, hull.neighbors)]  # n.y + off <= 0, unit normals
        A, b = _normalise_rows(eq[:, :-1].copy(), -eq[:, -1], field_name)
        return cls(A, b, V[np.sort(hull.vertices)], name, {"vertices": V.tolist()})

    @classmethod
    def box(cls, lower: Any, upper: Any, name: str = "", field_name: str = "box") -> "Polytope":
        """Axis-aligned box ``lower <= y <= upper`` (bounds within +-MAX_COORDINATE m)."""
        lo = _as_finite_array(lower, f"{field_name}.lower", 1)
        hi = _as_finite_array(upper, f"{field_name}.upper", 1)
        if lo.shape != hi.shape:
            raise ValidationError(field_name, f"lower and upper have different lengths {lo.size} and {hi.size}")
        if lo.size < 2:
            raise ValidationError(field_name, f"dimension must be >= 2, got {lo.size}")
        if lo.size > MAX_DIMENSION:  # 2**d corners
            raise ValidationError(field_name, f"dimension {lo.size} is more than the limit of {MAX_DIMENSION}")
        _check_magnitude(lo, f"{field_name}.lower")
        _check_magnitude(hi, f"{field_name}.upper")
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
        """``{y : A y <= b}``; rows are normalised to unit length.

        At most :data:`~belief_nlp._limits.MAX_POLYTOPE_FACES` rows; a
        bounded polytope's vertices (an unbounded one's offsets) must lie
        within +-:data:`~belief_nlp._limits.MAX_COORDINATE` m.
        """
        A_arr = _as_finite_array(A, f"{field_name}.A", 2)
        b_arr = _as_finite_array(b, f"{field_name}.b", 1)
        if A_arr.shape[0] != b_arr.shape[0]:
            raise ValidationError(f"{field_name}.b", f"A has {A_arr.shape[0]} rows but b has {b_arr.shape[0]} entries")
        _check_count(A_arr.shape[0], MAX_POLYTOPE_FACES, f"{field_name}.A", "half-spaces")
        d = A_arr.shape[1]
        if d < 2:
            raise ValidationError(f"{field_name}.A", f"dimension must be >= 2, got {d}")
        if d > MAX_DIMENSION:
            raise ValidationError(f"{field_name}.A", f"dimension {d} is more than the limit of {MAX_DIMENSION}")
        spec = {"A": A_arr.tolist(), "b": b_arr.tolist()}
        A_arr, b_arr = _normalise_rows(A_arr, b_arr, field_name)
        # b_i is the distance of face i from the origin; a face touching the
        # cube of half-width MAX_COORDINATE is at most sqrt(d) times that away.
        if b_arr.size and float(np.max(np.abs(b_arr))) > np.sqrt(d) * MAX_COORDINATE:
            raise ValidationError(f"{field_name}.b", f"face offsets (distances from the origin, rows of A "
                                                     f"normalised) must be at most sqrt({d}) * {MAX_COORDINATE:g} m, "
                                                     f"got {float(np.max(np.abs(b_arr))):.3g}")
        if not require_bounded:
            return cls(A_arr, b_arr, None, name, spec)
        if A_arr.shape[0] < d + 1:
            raise ValidationError(field_name, f"a bounded {d}-D polytope needs at least {d + 1} half-spaces, got {A_arr.shape[0]}")
        from scipy.optimize import linprog

        # Chebyshev centre: the largest ball inside (rows are unit), radius capped.
        scale = 1.0 + float(np.max(np.abs(b_arr)))
        res = linprog(np.r_[np.zeros(d), -1.0], A_ub=np.column_stack([A_arr, np.ones(len(b_arr))]), b_ub=b_arr,
                      bounds=[(None, None)] * d + [(None, 1e6 * scale)], method="highs")
        if res.status == 2 or (res.status == 0 and res.x[-1] < 0):
            raise ValidationError(field_name, "empty polytope: the half-spaces have no common point")
        if res.status == 0 and res.x[-1] <= _REL_TOL * scale:
            raise ValidationError(field_name, "degenerate polytope: it has no interior (flat)")
        if res.status != 0:
            raise ValidationError(field_name, f"the half-spaces could not be analysed ({res.message})")
        centre = res.x[:d]
        # bounded iff no coordinate can grow without limit
        for i in range(d):
            for sgn in (1.0, -1.0):
                c = np.zeros(d)
                c[i] = -sgn
                res = linprog(c, A_ub=A_arr, b_ub=b_arr, bounds=[(None, None)] * d, method="highs")
                if res.status == 3:
                    direction = ("+" if sgn > 0 else "-") + "xyz"[i] if d <= 3 else f"axis {i}"
                    raise ValidationError(field_name, f"unbounded polytope: it extends to infinity along {direction}")
                if res.status == 0 and abs(res.x[i]) > MAX_COORDINATE:
                    _check_magnitude(res.x[i:i + 1], field_name, "vertex coordinates")
        V = _halfspace_vertices(A_arr, b_arr, centre, field_name)
        if V.shape[0] < d + 1:
            raise ValidationError(field_name, "degenerate polytope (too few vertices)")
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
        """Dimension d of the space."""
        return int(self.A.shape[1])

    @property
    def n_faces(self) -> int:
        """Number of faces f (rows of ``A``)."""
        return int(self.A.shape[0])

    @property
    def bounded(self) -> bool:
        """True for a bounded polytope (one with ``vertices``)."""
        return self.vertices is not None

    def contains(self, y: Any, tol: float = 0.0) -> np.ndarray | bool:
        """Whether point(s) ``y`` (..., d) satisfy ``A y <= b + tol``."""
        y = np.asarray(y, dtype=float)
        if not np.all(np.isfinite(y)):
            raise ValidationError("y", "contains NaN or infinite values")
        if not np.isfinite(tol):
            raise ValidationError("tol", f"must be a finite number, got {tol!r}")
        out = np.all(y @ self.A.T <= self.b + tol, axis=-1)
        return bool(out) if out.ndim == 0 else out

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The axis-aligned box around the vertices.

        Returns
        -------
        lower, upper : ndarray, shape (d,)
            Smallest and largest vertex coordinate along each axis.

        Raises
        ------
        ValueError
            For an unbounded polytope (no vertices).
        """
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
        """Build from ``{"vertices": ...}``, ``{"box": {"lower", "upper"}}`` or ``{"A", "b"}``.

        Faults of structure (not a table, unknown or missing keys) raise
        :class:`~belief_nlp.errors.ScenarioFileError`, bad values
        :class:`~belief_nlp.errors.ValidationError`; both name the field.
        """
        if not isinstance(data, dict):
            raise ScenarioFileError(field_name, f"must be a table/object with one of the keys 'vertices', 'box' "
                                              f"or 'A'/'b', got {type(data).__name__}: {data!r}")
        unknown = set(data) - {"name", "vertices", "box", "A", "b"}
        if unknown:
            raise ScenarioFileError(f"{field_name}.{sorted(unknown)[0]}",
                                  "unknown key (a polytope takes 'name' and one of 'vertices', 'box' or 'A'/'b')")
        name = data.get("name", "")
        if not isinstance(name, str):
            raise ScenarioFileError(f"{field_name}.name", f"must be a string, got {type(name).__name__}")
        keys = [k for k in ("vertices", "box", "A") if k in data]
        if len(keys) != 1:
            given = ", ".join(repr(k) for k in keys) if keys else "none"
            raise ScenarioFileError(field_name, f"give exactly one of 'vertices', 'box' or 'A'/'b' (given: {given})")
        if "b" in data and "A" not in data:
            raise ScenarioFileError(f"{field_name}.b", "'b' is only allowed together with 'A'")
        if "vertices" in data:
            return cls.from_vertices(data["vertices"], name, f"{field_name}.vertices")
        if "box" in data:
            box = data["box"]
            if not isinstance(box, dict):
                raise ScenarioFileError(f"{field_name}.box", f"must be a table {{lower = [...], upper = [...]}}, "
                                                           f"got {type(box).__name__}")
            extra = set(box) - {"lower", "upper"}
            if extra:
                raise ScenarioFileError(f"{field_name}.box.{sorted(extra)[0]}", "unknown key (a box has 'lower' and 'upper')")
            for key in ("lower", "upper"):
                if key not in box:
                    raise ScenarioFileError(f"{field_name}.box.{key}", "missing")
            return cls.box(box["lower"], box["upper"], name, f"{field_name}.box")
        if "b" not in data:
            raise ScenarioFileError(f"{field_name}.b", "missing ('A' needs 'b')")
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
