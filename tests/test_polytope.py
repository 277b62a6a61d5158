"""Polytope construction, validation and serialisation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from belief_nlp.errors import ScenarioFileError, ValidationError
from belief_nlp.polytope import Polytope

SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


def _raises(fn, field, *words, exc=ValidationError):
    """fn() raises ``exc`` whose .field is ``field`` and whose message names it and ``words``."""
    with pytest.raises(exc) as info:
        fn()
    err = info.value
    assert isinstance(err, ValidationError) and isinstance(err, ValueError)
    assert err.field == field
    msg = str(err)
    assert field in msg
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"
    return err


# ------------------------------------------------------------------ building
def test_polygon_either_orientation_gives_same_halfspaces():
    ccw = Polytope.from_vertices(SQUARE)
    cw = Polytope.from_vertices(SQUARE[::-1])
    assert np.array_equal(ccw.vertices, cw.vertices) or np.allclose(
        np.sort(ccw.vertices, axis=0), np.sort(cw.vertices, axis=0))
    key = lambda P: sorted(zip(map(tuple, np.round(P.A, 12)), np.round(P.b, 12)))  # noqa: E731
    assert key(ccw) == key(cw)
    for P in (ccw, cw):
        assert np.allclose(np.linalg.norm(P.A, axis=1), 1.0)
        # every vertex is on the boundary, the centre strictly inside
        assert np.all(P.vertices @ P.A.T <= P.b + 1e-12)
        assert P.contains([0.5, 0.5]) and not P.contains([1.5, 0.5])


def test_polygon_normals_point_outward_and_vertices_ccw():
    tri = Polytope.from_vertices([[0, 0], [0, 1], [2, 0]])  # clockwise input
    V = tri.vertices
    area2 = np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1])
    assert area2 > 0
    centre = V.mean(axis=0)
    assert np.all(tri.A @ centre < tri.b)
    for a, b in zip(tri.A, tri.b):
        assert a @ (centre + 10 * a) > b  # moving along the normal leaves the polygon


def test_box_matches_vertices_and_halfspaces():
    box = Polytope.box([0.2, 0.1], [0.5, 0.4])
    poly = Polytope.from_vertices([[0.2, 0.1], [0.5, 0.1], [0.5, 0.4], [0.2, 0.4]])
    hs = Polytope.from_halfspaces([[1, 0], [0, 1], [-1, 0], [0, -1]], [0.5, 0.4, -0.2, -0.1])
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 0.6, size=(2000, 2))
    assert np.array_equal(box.contains(pts), poly.contains(pts))
    assert np.array_equal(box.contains(pts), hs.contains(pts))
    assert np.allclose(np.sort(hs.vertices, axis=0), np.sort(box.vertices, axis=0))


def test_halfspace_rows_are_normalised():
    P = Polytope.from_halfspaces([[2.0, 0.0], [0.0, 3.0], [-1.0, -1.0]], [2.0, 3.0, 0.0])
    assert np.allclose(np.linalg.norm(P.A, axis=1), 1.0)
    assert P.contains([0.5, 0.5]) and not P.contains([1.1, 0.5])
    assert np.allclose(P.b, [1.0, 1.0, 0.0])


def test_3d_box_and_hull():
    cube = Polytope.box([0, 0, 0], [1, 1, 1])
    assert cube.dim == 3 and cube.n_faces == 6 and cube.vertices.shape == (8, 3)
    tet = Polytope.from_vertices([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert tet.n_faces == 4
    assert np.allclose(np.linalg.norm(tet.A, axis=1), 1.0)
    assert tet.contains([0.1, 0.1, 0.1]) and not tet.contains([0.5, 0.5, 0.5])
    hull = Polytope.from_vertices(cube.vertices)
    assert hull.n_faces == 6  # coplanar facet triangles merged


def test_single_halfspace_and_complement():
    h = Polytope.halfspace([0, 2], 1.0)
    assert not h.bounded and h.n_faces == 1
    assert np.allclose(h.A, [[0, 1]]) and np.allclose(h.b, [0.5])
    walls = Polytope.box([0, 0], [1, 1]).complement_halfspaces("wall")
    assert len(walls) == 4 and all(w.n_faces == 1 for w in walls)
    inside = np.array([0.5, 0.5])
    assert not any(w.contains(inside) for w in walls)
    assert sum(w.contains([1.5, 0.5]) for w in walls) == 1


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize("verts, words", [
    ([[0, 0], [1, 0]], ("at least 3 vertices",)),
    ([[0, 0], [1, 1], [1, 0], [0, 1]], ("self-intersecting",)),            # bow tie
    ([[0, 0], [2, 2], [2, 0], [0, 3]], ("self-intersecting",)),            # asymmetric bow tie
    ([[np.cos(t), np.sin(t)] for t in np.arange(5) * 4 * np.pi / 5], ("self-intersecting",)),  # pentagram
    ([[0, 0], [1, 0], [1, 0], [1, 1]], ("repeated vertex", "1 and 2")),
    ([[0, 0], [1, 0], [0, 0], [1, 1]], ("repeated vertex", "0 and 2")),   # not adjacent
    ([[0, 0], [1, 0], [0.5, 0.2], [1, 1], [0, 1]], ("not convex",)),
    ([[0, 0], [1, 0], [2, 0]], ("degenerate",)),
    ([[0, 0], [1, 0], [2, 0], [1, 1]], ("collinear",)),
    ([[1, 1], [1, 1], [1, 1]], ("coincide",)),
    ([[0, 0], [1, np.nan], [0, 1]], ("NaN",)),
    ([[0, 0], [1, np.inf], [0, 1]], ("infinite",)),
    ([[0, 0], [1], [0, 1]], ("equal lengths",)),
    ("square", ("list of lists of numbers",)),
    ([[True, False], [True, True], [False, True]], ("booleans",)),
    ([0.0, 1.0, 2.0], ("shape",)),
])
def test_bad_polygons(verts, words):
    _raises(lambda: Polytope.from_vertices(verts, field_name="obstacles[3].vertices"),
            "obstacles[3].vertices", *words)


@pytest.mark.parametrize("verts, words", [
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], ("at least 4",)),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], ("degenerate",)),            # coplanar
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.1, 0.1, 0.1]], ("not extreme",)),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0]], ("repeated vertex", "1 and 4")),
])
def test_bad_3d_polytopes(verts, words):
    _raises(lambda: Polytope.from_vertices(verts, field_name="obstacles[0].vertices"),
            "obstacles[0].vertices", *words)


def test_bad_boxes():
    _raises(lambda: Polytope.box([0, 0], [0, 1], field_name="target.box"), "target.box", "degenerate")
    _raises(lambda: Polytope.box([0, 0], [1, 1, 1], field_name="target.box"), "target.box", "lengths")
    _raises(lambda: Polytope.box([0], [1], field_name="target.box"), "target.box", ">= 2")
    _raises(lambda: Polytope.box([0, "a"], [1, 1], field_name="target.box"), "target.box.lower")


def test_bad_halfspaces():
    f = "domain"
    _raises(lambda: Polytope.from_halfspaces([[0, 0], [0, 1], [-1, -1]], [1, 1, 1], field_name=f),
            "domain.A", "zero normal")
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [0, 1], [-1, -1]], [1, 1], field_name=f),
            "domain.b", "3 rows", "2 entries")
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [-1, 0], [0, 1], [0, -1]], [0.1, -0.2, 1, 0],
                                             field_name=f), "domain", "empty")
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [-1, 0], [0, 1], [0, -1]], [0.1, -0.1, 1, 0],
                                             field_name=f), "domain", "no interior")
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [0, 1]], [1, 1], field_name=f), "domain", "at least 3")
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [0, 1], [0, -1]], [1, 1, 1], field_name=f),
            "domain", "unbounded", "-x")  # a strip
    _raises(lambda: Polytope.from_halfspaces([[1, 0], [0, 1], [-1, 0]], [1, 1, 1], field_name=f),
            "domain", "unbounded", "-y")
    _raises(lambda: Polytope.from_halfspaces([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, 0]], [1, 1, 1, 0],
                                             field_name=f), "domain", "unbounded", "-z")
    _raises(lambda: Polytope.from_halfspaces([[1.0], [-1.0]], [1, 1], field_name=f), "domain.A", ">= 2")


@pytest.mark.parametrize("data, field, words", [
    ("box", "obstacles[1]", ("table",)),
    ([[0, 0], [1, 0], [0, 1]], "obstacles[1]", ("table",)),
    ({}, "obstacles[1]", ("exactly one",)),
    ({"vertices": SQUARE, "box": {"lower": [0, 0], "upper": [1, 1]}}, "obstacles[1]", ("exactly one",)),
    ({"vertices": SQUARE, "colour": "red"}, "obstacles[1].colour", ("unknown key",)),
    ({"vertices": SQUARE, "name": 3}, "obstacles[1].name", ("string",)),
    ({"vertices": SQUARE, "b": [1, 2]}, "obstacles[1].b", ("only allowed together with 'A'",)),
    ({"A": [[1, 0], [0, 1], [-1, -1]]}, "obstacles[1].b", ("missing",)),
    ({"box": [0, 1]}, "obstacles[1].box", ("table",)),
    ({"box": {"lower": [0, 0]}}, "obstacles[1].box.upper", ("missing",)),
    ({"box": {"lower": [0, 0], "upper": [1, 1], "lo": 1}}, "obstacles[1].box.lo", ("unknown key",)),
])
def test_from_dict_structure_errors(data, field, words):
    _raises(lambda: Polytope.from_dict(data, "obstacles[1]"), field, *words, exc=ScenarioFileError)


def test_from_dict_value_errors_name_the_nested_field():
    err = _raises(lambda: Polytope.from_dict({"vertices": [[0, 0], [1, 1], [1, 0], [0, 1]]}, "obstacles[2]"),
                  "obstacles[2].vertices", "self-intersecting")
    assert not isinstance(err, ScenarioFileError)
    _raises(lambda: Polytope.from_dict({"box": {"lower": [0, 0], "upper": [0, 1]}}, "target"),
            "target.box", "degenerate")


# ------------------------------------------------------------ serialisation
@pytest.mark.parametrize("poly", [
    Polytope.from_vertices([[0.145, 0.40], [0.105, 0.34], [0.225, 0.30], [0.225, 0.36]], name="o1"),
    Polytope.from_vertices([[0.3, 0.1], [0.1, 0.1], [0.2, 0.3]]),          # clockwise
    Polytope.box([0.1, 0.2], [0.3, 0.7], name="b"),
    Polytope.box([0, 0, 0], [1, 2, 3]),
    Polytope.from_halfspaces([[3.0, 0.1], [0.0, 7.0], [-1.0, -1.0]], [2.0, 3.0, 0.1]),
    Polytope.from_vertices([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.3, 1]]),
])
def test_dict_round_trip_is_bit_exact(poly):
    back = Polytope.from_dict(poly.to_dict())
    assert back == poly
    assert np.array_equal(back.A, poly.A) and np.array_equal(back.b, poly.b)
    assert np.array_equal(back.vertices, poly.vertices)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-10, 10), st.floats(-10, 10)), min_size=1, max_size=6))
def test_normalised_rows_are_left_alone(rows):
    """A polytope built from already-unit rows (e.g. Polytope(A, b) saved via
    A, b) reloads with bit-identical A and b."""
    A = np.array(rows, dtype=float)
    A = A[np.linalg.norm(A, axis=1) > 1e-3]
    if A.shape[0] == 0:
        return
    A = A / np.linalg.norm(A, axis=1)[:, None]
    b = np.linspace(0.1, 1.0, A.shape[0])
    P = Polytope.from_halfspaces(A, b, require_bounded=False)
    assert np.array_equal(P.A, A) and np.array_equal(P.b, b)
    raw = Polytope(P.A, P.b)
    back = Polytope.from_dict(raw.to_dict(), require_bounded=False)
    assert np.array_equal(back.A, raw.A) and np.array_equal(back.b, raw.b)


@settings(max_examples=40, deadline=None)
@given(st.integers(3, 9), st.floats(0.1, 5.0), st.floats(0, 6.28), st.booleans(), st.integers(0, 2**32 - 1))
def test_random_convex_polygons_accepted_and_match_vertices(n, r, phase, clockwise, seed):
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n)) + phase
    ang = np.unique(np.round(ang, 3))
    if len(ang) < 3 or np.max(np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))) >= np.pi - 1e-3:
        return  # not a polygon with the origin strictly inside
    V = r * np.column_stack([np.cos(ang), np.sin(ang)])
    if clockwise:
        V = V[::-1]
    P = Polytope.from_vertices(V)
    assert P.n_faces == len(ang)
    assert np.all(P.vertices @ P.A.T <= P.b + 1e-9)
    assert P.contains([0.0, 0.0])
