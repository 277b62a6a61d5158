"""Scenarios: built-ins, validation (one test per class of bad input), files."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ScenarioFileError, ValidationError
from belief_nlp.polytope import Polytope
from belief_nlp.scenario import Scenario, load_scenario, save_scenario, scenario_from_dict

DOCS = Path(__file__).resolve().parents[1] / "docs" / "scenario_schema.md"


@pytest.fixture(scope="module")
def base_dict():
    return bn.load_scenario("paper-multi").to_dict()


def _bad(data, field, *words, exc=ValidationError):
    """scenario_from_dict(data) raises ``exc``; .field == field; message names field and words."""
    with pytest.raises(exc) as info:
        scenario_from_dict(data)
    err = info.value
    assert isinstance(err, ValidationError) and isinstance(err, ValueError)
    assert err.field == field, str(err)
    msg = str(err)
    assert field in msg
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"
    return err


def _mutated(base, fn):
    d = copy.deepcopy(base)
    fn(d)
    return d


# ------------------------------------------------------------------ built-ins
def test_list_scenarios_has_the_builtins():
    names = bn.list_scenarios()
    assert {"paper-multi", "quad", "cube3d", "tutorial"} <= set(names)
    assert names == sorted(names)


def test_paper_multi_matches_reference():
    sc = bn.load_scenario("paper-multi")
    assert sc.dim == 2 and len(sc.obstacles) == 6 and len(sc.walls) == 4
    assert np.array_equal(sc.x0, [0.15, 0.5])
    assert np.array_equal(sc.P0, 1e-9 * np.eye(2))
    assert np.array_equal(sc.W, 0.2e-3 * np.eye(2))
    assert np.array_equal(sc.W_rate, 1e-3 * np.eye(2))
    ob5 = sc.obstacles[4]
    assert ob5.name == "obstacle 5"
    assert sorted(map(tuple, ob5.vertices.tolist())) == sorted([(0.49, 0.30), (0.50, 0.20), (0.65, 0.14),
                                                                (0.69, 0.27)])
    lo, hi = sc.target.bounding_box()
    assert np.allclose(lo, [0.6, 0.0]) and np.allclose(hi, [0.7, 0.1])
    # 90 % in 2-D: chi2 = -2 ln(0.1), the closed form of the chi-square(2) quantile
    assert sc.confidence == 0.9
    assert sc.chi2 == pytest.approx(-2 * math.log(0.1), rel=1e-12)
    assert sc.chi2 == pytest.approx(4.60517, abs=1e-5)


def test_quad_tutorial_cube3d_shapes():
    quad = bn.load_scenario("quad")
    assert len(quad.obstacles) == 3 and np.array_equal(quad.x0, [0.1, 0.9])
    tut = bn.load_scenario("tutorial")
    # Fig. 1: L = 4 domain faces, M = 2 obstacles, N = 4 target faces, 6 steps
    assert tut.domain.n_faces == 4 and len(tut.obstacles) == 2 and tut.target.n_faces == 4 and tut.K == 6
    cube = bn.load_scenario("cube3d")
    assert cube.dim == 3 and cube.x0.shape == (3,) and cube.P0.shape == (3, 3)
    assert all(o.dim == 3 for o in cube.obstacles) and len(cube.walls) == 6
    assert cube.chi2 == pytest.approx(6.251388631170325, rel=1e-9)  # chi-square(3) 0.9 quantile


def test_hazards_are_obstacles_then_walls():
    sc = bn.load_scenario("paper-multi")
    names = [h.name for h in sc.hazards]
    assert names[:6] == [f"obstacle {i}" for i in range(1, 7)]
    assert names[6:] == [f"wall {i}" for i in range(4)]
    for w in sc.walls:  # the start is strictly inside the domain, i.e. outside every wall
        assert not w.contains(sc.x0)


def test_unnamed_obstacles_get_default_names():
    sc = bn.load_scenario("quad")
    bare = sc.with_options(obstacles=[Polytope(o.A, o.b, o.vertices) for o in sc.obstacles])
    assert [o.name for o in bare.obstacles] == ["obstacle 1", "obstacle 2", "obstacle 3"]


# ----------------------------------------------------------- chi2/confidence
def test_confidence_default_and_chi2_override():
    sc = bn.load_scenario("paper-multi")
    d = sc.to_dict()
    d.pop("confidence")
    assert scenario_from_dict(d).confidence == 0.9
    d["chi2"] = 9.21
    sc2 = scenario_from_dict(d)
    assert sc2.chi2 == 9.21 and sc2.confidence is None
    assert sc.with_options(chi2_value=5.0).chi2 == 5.0
    assert sc.with_options(chi2_value=5.0).with_options(confidence=0.99).chi2 == pytest.approx(-2 * math.log(0.01))
    with pytest.raises(ValidationError) as info:
        sc.with_options(chi2_value=5.0, confidence=0.95)
    assert info.value.field == "chi2"


def test_risk_is_an_alternative_for_the_collision_level():
    """``risk``: an end-to-end budget; confidence / chi2 stay (the target's level)."""
    sc = bn.load_scenario("paper-multi")
    assert sc.risk is None and "risk" not in sc.to_dict()
    budget = sc.with_options(risk=0.05)
    assert budget.risk == 0.05 and budget.confidence == 0.9 and budget.chi2 == sc.chi2
    assert budget.to_dict()["risk"] == 0.05 and "risk=0.05" in repr(budget)
    assert budget != sc and budget.with_options(risk=None) == sc
    assert isinstance(sc.with_options(risk=np.float32(0.25)).risk, float)
    d = sc.to_dict()
    d.pop("confidence")
    d["risk"] = 0.05
    assert scenario_from_dict(d).confidence == 0.9                 # the target's level keeps its default
    d["chi2"] = 9.21
    assert scenario_from_dict(d).chi2 == 9.21 and scenario_from_dict(d).risk == 0.05


# ---------------------------------------------------------------- validation
# One entry per class of bad input: (label, mutation of a valid dict, field, words in message, type)
SE, VE = ScenarioFileError, ValidationError
TRI = [[0.8, 0.8], [0.9, 0.8], [0.85, 0.9]]
BAD_CASES = [
    # polygons
    ("non-convex polygon", lambda d: d["obstacles"].__setitem__(0, {"vertices": [[0.1, 0.1], [0.3, 0.1], [0.2, 0.15],
                                                                                  [0.3, 0.3], [0.1, 0.3]]}),
     "obstacles[0].vertices", ("not convex",), VE),
    ("self-intersecting polygon", lambda d: d["obstacles"].__setitem__(
        1, {"vertices": [[0.8, 0.8], [0.9, 0.9], [0.9, 0.8], [0.8, 0.9]]}),
     "obstacles[1].vertices", ("self-intersecting",), VE),
    ("repeated vertices", lambda d: d["obstacles"].__setitem__(
        2, {"vertices": [[0.8, 0.8], [0.9, 0.8], [0.9, 0.8], [0.85, 0.9]]}),
     "obstacles[2].vertices", ("repeated vertex",), VE),
    ("degenerate polygon", lambda d: d["obstacles"].__setitem__(0, {"vertices": [[0.8, 0.8], [0.85, 0.8], [0.9, 0.8]]}),
     "obstacles[0].vertices", ("degenerate",), VE),
    ("too few vertices", lambda d: d["obstacles"].__setitem__(0, {"vertices": [[0.8, 0.8], [0.9, 0.8]]}),
     "obstacles[0].vertices", ("at least 3 vertices",), VE),
    ("NaN vertex", lambda d: d["obstacles"].__setitem__(0, {"vertices": [[0.8, 0.8], [0.9, float("nan")], [0.85, 0.9]]}),
     "obstacles[0].vertices", ("NaN",), VE),
    ("inf in box", lambda d: d.__setitem__("target", {"box": {"lower": [0.6, 0.0], "upper": [float("inf"), 0.1]}}),
     "target.box.upper", ("infinite",), VE),
    ("degenerate box", lambda d: d.__setitem__("target", {"box": {"lower": [0.6, 0.0], "upper": [0.6, 0.1]}}),
     "target.box", ("degenerate",), VE),
    ("unbounded domain", lambda d: d.__setitem__("domain", {"A": [[1, 0], [0, 1], [-1, 0]], "b": [1, 1, 0]}),
     "domain", ("unbounded",), VE),
    ("empty half-spaces", lambda d: d["obstacles"].__setitem__(0, {"A": [[1, 0], [-1, 0], [0, 1], [0, -1]],
                                                                   "b": [0.1, -0.2, 1, 0]}),
     "obstacles[0]", ("empty",), VE),
    ("zero normal", lambda d: d["obstacles"].__setitem__(0, {"A": [[0, 0], [0, 1], [-1, -1]], "b": [1, 1, 1]}),
     "obstacles[0].A", ("zero normal",), VE),
    # dimensions
    ("2-D polygon with 3-D obstacles", lambda d: (
        d.__setitem__("obstacles", [{"box": {"lower": [0.8, 0.8, 0], "upper": [0.9, 0.9, 1]}},
                                    {"vertices": TRI}])),
     "obstacles[0]", ("3-D", "domain is 2-D"), VE),
    ("2-D obstacle in a 3-D scenario", lambda d: d["obstacles"].__setitem__(1, {"vertices": TRI}),
     "obstacles[1]", ("2-D", "domain is 3-D"), "cube3d"),
    ("3-D domain with 2-D rest", lambda d: d.__setitem__("domain", {"box": {"lower": [0, 0, 0], "upper": [1, 1, 1]}}),
     "target", ("2-D", "domain is 3-D"), VE),
    ("target dimension", lambda d: d.__setitem__("target", {"box": {"lower": [0.6, 0, 0], "upper": [0.7, 0.1, 0.1]}}),
     "target", ("3-D",), VE),
    ("1-D domain", lambda d: d.__setitem__("domain", {"box": {"lower": [0], "upper": [1]}}),
     "domain.box", (">= 2",), VE),
    ("x0 wrong length", lambda d: d["start"].__setitem__("x", [0.15, 0.5, 0.0]),
     "start.x", ("2 entries",), VE),
    ("x0 nested", lambda d: d["start"].__setitem__("x", [[0.15, 0.5]]), "start.x", ("shape",), VE),
    ("x0 NaN", lambda d: d["start"].__setitem__("x", [0.15, float("nan")]), "start.x", ("NaN",), VE),
    # covariances
    ("P0 with NaN", lambda d: d["start"].__setitem__("P", [[float("nan"), 0.0], [0.0, 1e-9]]),
     "start.P", ("NaN",), VE),
    ("P0 3x3 in 2-D", lambda d: d["start"].__setitem__("P", np.eye(3).tolist()), "start.P", ("2x2", "(3, 3)"), VE),
    ("P0 diagonal wrong length", lambda d: d["start"].__setitem__("P", [1e-9, 1e-9, 1e-9]),
     "start.P", ("2 entries",), VE),
    ("P0 not symmetric", lambda d: d["start"].__setitem__("P", [[1e-4, 1e-5], [0.0, 1e-4]]),
     "start.P", ("not symmetric",), VE),
    ("P0 indefinite", lambda d: d["start"].__setitem__("P", [[1e-4, 0.0], [0.0, -1e-4]]),
     "start.P", ("not positive semidefinite",), VE),
    ("P0 a string", lambda d: d["start"].__setitem__("P", "small"), "start.P", ("number",), VE),
    ("P0 a bool", lambda d: d["start"].__setitem__("P", True), "start.P", ("number",), VE),
    ("W not PD", lambda d: d["noise"].__setitem__("W", [[2e-4, 0.0], [0.0, 0.0]]),
     "noise.W", ("not positive definite",), VE),
    ("W negative", lambda d: d["noise"].__setitem__("W", -2e-4), "noise.W", ("not positive definite",), VE),
    ("W_rate not PD", lambda d: d["noise"].__setitem__("W_rate", [[1e-3, 2e-3], [2e-3, 1e-3]]),
     "noise.W_rate", ("not positive definite",), VE),
    # start / target placement
    ("start ellipse hits an obstacle", lambda d: d["start"].__setitem__("x", [0.5, 0.45]),
     "start", ("not clear of obstacle 6",), VE),
    ("start ellipse outside the domain", lambda d: d["start"].__setitem__("P", 1e-2),
     "start", ("not inside the domain",), VE),
    ("start mean outside the domain", lambda d: d["start"].__setitem__("x", [1.5, 0.5]),
     "start", ("not inside the domain",), VE),
    ("target outside the domain", lambda d: d.__setitem__("target", {"box": {"lower": [0.9, 0.9],
                                                                            "upper": [1.1, 1.0]}}),
     "target", ("not inside the domain",), VE),
    # scalars
    ("negative alpha", lambda d: d.__setitem__("alpha", -0.1), "alpha", (">= 0",), VE),
    ("NaN alpha", lambda d: d.__setitem__("alpha", float("nan")), "alpha", ("finite",), VE),
    ("confidence 1.0", lambda d: d.__setitem__("confidence", 1.0), "confidence", ("between 0 and 1",), VE),
    ("confidence 0", lambda d: d.__setitem__("confidence", 0.0), "confidence", ("between 0 and 1",), VE),
    ("chi2 negative", lambda d: (d.pop("confidence"), d.__setitem__("chi2", -1.0)), "chi2", ("> 0",), VE),
    ("chi2 infinite", lambda d: (d.pop("confidence"), d.__setitem__("chi2", float("inf"))), "chi2", ("finite",), VE),
    ("both chi2 and confidence", lambda d: d.__setitem__("chi2", 4.6), "chi2", ("not both",), SE),
    ("K = 0", lambda d: d["horizon"].__setitem__("K", 0), "horizon.K", ("positive integer",), VE),
    ("K negative", lambda d: d["horizon"].__setitem__("K", -3), "horizon.K", ("positive integer",), VE),
    # file structure: unknown / missing keys and wrong types
    ("unknown top-level key", lambda d: d.__setitem__("obstacle", []), "obstacle", ("unknown key",), SE),
    ("unknown key in start", lambda d: d["start"].__setitem__("sigma", 1), "start.sigma", ("unknown key",), SE),
    ("unknown key in noise", lambda d: d["noise"].__setitem__("V", 1), "noise.V", ("unknown key",), SE),
    ("unknown key in horizon", lambda d: d["horizon"].__setitem__("N", 3), "horizon.N", ("unknown key",), SE),
    ("unknown key in obstacle", lambda d: d["obstacles"][0].__setitem__("colour", "red"),
     "obstacles[0].colour", ("unknown key",), SE),
    ("missing start", lambda d: d.pop("start"), "start", ("missing",), SE),
    ("missing noise", lambda d: d.pop("noise"), "noise", ("missing",), SE),
    ("missing domain", lambda d: d.pop("domain"), "domain", ("missing",), SE),
    ("missing target", lambda d: d.pop("target"), "target", ("missing",), SE),
    ("missing start.x", lambda d: d["start"].pop("x"), "start.x", ("missing",), SE),
    ("missing start.P", lambda d: d["start"].pop("P"), "start.P", ("missing",), SE),
    ("missing noise.W", lambda d: d["noise"].pop("W"), "noise.W", ("missing",), SE),
    ("obstacle as a string", lambda d: d["obstacles"].__setitem__(3, "obstacle 4"), "obstacles[3]", ("table",), SE),
    ("obstacles as a table", lambda d: d.__setitem__("obstacles", {"vertices": TRI}), "obstacles", ("array",), SE),
    ("obstacle without geometry", lambda d: d["obstacles"].__setitem__(0, {"name": "x"}),
     "obstacles[0]", ("exactly one",), SE),
    ("obstacle name not a string", lambda d: d["obstacles"][0].__setitem__("name", 4),
     "obstacles[0].name", ("string",), SE),
    ("box not a table", lambda d: d.__setitem__("target", {"box": [0.6, 0.0, 0.7, 0.1]}), "target.box", ("table",), SE),
    ("A without b", lambda d: d["obstacles"].__setitem__(0, {"A": [[1, 0], [0, 1], [-1, -1]]}),
     "obstacles[0].b", ("missing",), SE),
    ("start a number", lambda d: d.__setitem__("start", 0.15), "start", ("table",), SE),
    ("horizon a number", lambda d: d.__setitem__("horizon", 20), "horizon", ("table",), SE),
    ("planner a string", lambda d: d.__setitem__("planner", "fast"), "planner", ("table",), SE),
    ("x0 a string", lambda d: d["start"].__setitem__("x", "origin"), "start.x", ("list of numbers",), VE),
    ("alpha a string", lambda d: d.__setitem__("alpha", "0.1"), "alpha", ("number", "str"), SE),
    ("alpha a bool", lambda d: d.__setitem__("alpha", True), "alpha", ("number", "bool"), SE),
    ("confidence a string", lambda d: d.__setitem__("confidence", "90%"), "confidence", ("number",), SE),
    ("risk a string", lambda d: d.__setitem__("risk", "5%"), "risk", ("number", "str"), SE),
    ("risk a bool", lambda d: d.__setitem__("risk", True), "risk", ("number", "bool"), SE),
    ("risk zero", lambda d: d.__setitem__("risk", 0), "risk", ("(0, 0.5)",), VE),
    ("risk 0.5", lambda d: d.__setitem__("risk", 0.5), "risk", ("(0, 0.5)",), VE),
    ("risk negative", lambda d: d.__setitem__("risk", -0.01), "risk", ("(0, 0.5)",), VE),
    ("risk spent by the start", lambda d: (d.__setitem__("risk", 0.01), d["start"].__setitem__("P", 2e-3)),
     "risk", ("start belief", "obstacle 1"), VE),
    ("K a float", lambda d: d["horizon"].__setitem__("K", 2.5), "horizon.K", ("integer",), SE),
    ("K a string", lambda d: d["horizon"].__setitem__("K", "20"), "horizon.K", ("integer",), SE),
    ("K a bool", lambda d: d["horizon"].__setitem__("K", True), "horizon.K", ("integer",), SE),
    ("name not a string", lambda d: d.__setitem__("name", 7), "name", ("string",), SE),
    ("description not a string", lambda d: d.__setitem__("description", ["a"]), "description", ("string",), SE),
]


@pytest.mark.parametrize("label, mutate, field, words, exc", BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_scenario_inputs(base_dict, label, mutate, field, words, exc):
    if exc == "cube3d":
        base, exc = bn.load_scenario("cube3d").to_dict(), ValidationError
    else:
        base = base_dict
    _bad(_mutated(base, mutate), field, *words, exc=exc)


def test_top_level_not_a_table():
    with pytest.raises(ScenarioFileError) as info:
        scenario_from_dict([1, 2, 3])
    assert info.value.field == "file" and "top level" in str(info.value)


def test_constructor_validates_too():
    sc = bn.load_scenario("paper-multi")
    cases = [
        (dict(obstacles="abc"), "obstacles", "sequence"),
        (dict(obstacles=[sc.obstacles[0], "x"]), "obstacles[1]", "Polytope"),
        (dict(domain=None), "domain", "bounded"),
        (dict(target=Polytope.halfspace([1, 0], 0.7)), "target", "bounded"),
        (dict(P0="x"), "start.P", "number"),
        (dict(P0=np.full((2, 2), np.nan)), "start.P", "NaN"),
        (dict(x0=None), "start.x", "numbers"),
        (dict(W=np.zeros((2, 2))), "noise.W", "positive definite"),
        (dict(alpha=-1.0), "alpha", ">= 0"),
        (dict(alpha=True), "alpha", ">= 0"),
        (dict(confidence=1.0), "confidence", "between"),
        (dict(chi2_value=0.0), "chi2", "> 0"),
        (dict(chi2_value=True), "chi2", "> 0"),
        (dict(K=0), "horizon.K", "positive"),
        (dict(K=3.0), "horizon.K", "positive"),
        (dict(planner=[1]), "planner", "table"),
        (dict(name=1), "name", "string"),
    ]
    for change, field, word in cases:
        with pytest.raises(ValidationError) as info:
            sc.with_options(**change)
        assert info.value.field == field, (change, str(info.value))
        assert field in str(info.value) and word in str(info.value), (change, str(info.value))


def test_valid_variants_are_accepted():
    sc = bn.load_scenario("paper-multi")
    d = sc.to_dict()
    d["start"]["P"] = 0.0                      # an exact start (P0 = 0) is allowed
    d["noise"]["W"] = [2e-4, 3e-4]             # diagonal shorthand
    d["noise"].pop("W_rate")                   # defaults to W
    d.pop("horizon")
    d.pop("planner")
    d["obstacles"] = []
    s2 = scenario_from_dict(d)
    assert np.array_equal(s2.P0, np.zeros((2, 2)))
    assert np.array_equal(s2.W, np.diag([2e-4, 3e-4])) and np.array_equal(s2.W_rate, s2.W)
    assert s2.K is None and s2.planner == {} and s2.obstacles == ()
    assert sc.with_options(K=np.int64(7)).K == 7
    assert np.array_equal(sc.with_options(P0=np.array(2e-9)).P0, 2e-9 * np.eye(2))   # 0-d array = scalar
    assert np.array_equal(sc.with_options(W=np.float32(1e-4)).W, float(np.float32(1e-4)) * np.eye(2))


# ---------------------------------------------------------------------- files
def _assert_bit_exact(a: Scenario, b: Scenario):
    assert a == b
    for f in ("x0", "P0", "W", "W_rate"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    for pa, pb in zip((a.domain, a.target) + a.obstacles, (b.domain, b.target) + b.obstacles):
        assert pa.name == pb.name
        assert np.array_equal(pa.A, pb.A) and np.array_equal(pa.b, pb.b)
        assert np.array_equal(pa.vertices, pb.vertices)
    assert len(a.obstacles) == len(b.obstacles)
    assert (a.alpha, a.confidence, a.chi2, a.K, a.planner, a.name, a.description, a.risk) == \
        (b.alpha, b.confidence, b.chi2, b.K, b.planner, b.name, b.description, b.risk)


def _constructed_scenarios():
    """Scenarios built in code from vertices, boxes and half-spaces, 2-D and 3-D."""
    rng = np.random.default_rng(7)
    R = np.linalg.qr(rng.normal(size=(2, 2)))[0]
    P0 = R @ np.diag([1.234567e-5, 3.3e-6]) @ R.T
    P0 = 0.5 * (P0 + P0.T)
    yield Scenario(
        domain=Polytope.from_halfspaces([[1.0, 0.1], [0.0, 3.0], [-1.0, 0.0], [0.2, -1.0]], [1.0, 2.9, 0.0, 0.05]),
        target=Polytope.from_vertices([[0.71, 0.8], [0.9, 0.81], [0.8, 0.6]]),    # clockwise
        obstacles=(Polytope.box([0.3, 0.3], [0.5, 0.5 + 1 / 3], name="box"),
                   Polytope.from_vertices([[0.6, 0.1], [0.7, 0.1], [0.7, 0.2 + 1e-7], [0.6, 0.2]]),
                   Polytope.from_halfspaces([[1, 1], [-1, 0], [0, -1]], [1.7, -0.6, -0.6], name="hs")),
        x0=np.array([0.1 + 1 / 30, 0.2]), P0=P0, W=np.diag([1 / 3 * 1e-4, 2e-4]),
        W_rate=np.array([[1e-3, 1e-4], [1e-4, 2e-3]]), alpha=1 / 7, chi2_value=4.2 + 1e-13,
        K=13, planner={"max_radius": 0.25, "n_nodes": 300, "note": "x"}, name="built", description="in code")
    yield Scenario(
        domain=Polytope.box([0, 0, 0], [1, 1, 1]), target=Polytope.box([0.7, 0.7, 0.7], [0.9, 0.9, 0.95]),
        obstacles=(Polytope.from_vertices([[0.4, 0.4, 0.4], [0.6, 0.4, 0.4], [0.5, 0.6, 0.4], [0.5, 0.5, 0.6]]),
                   Polytope.from_halfspaces(np.vstack([np.eye(3), -np.eye(3)]) * 2.0,
                                            2.0 * np.array([0.3, 0.9, 0.9, -0.2, -0.7, -0.1]))),
        x0=np.array([0.1, 0.1, 0.1]), P0=np.zeros((3, 3)), W=1e-4 * np.eye(3), W_rate=1e-3 * np.eye(3),
        confidence=0.95, risk=1 / 30)


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize("name", ["paper-multi", "quad", "cube3d", "tutorial"])
def test_builtin_round_trip(tmp_path, name, suffix):
    sc = bn.load_scenario(name)
    back = load_scenario(save_scenario(sc, tmp_path / f"s{suffix}"))
    _assert_bit_exact(sc, back)
    # and a second generation is identical text
    again = save_scenario(back, tmp_path / f"t{suffix}")
    assert again.read_text() == (tmp_path / f"s{suffix}").read_text()


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize("index", [0, 1])
def test_constructed_round_trip(tmp_path, index, suffix):
    sc = list(_constructed_scenarios())[index]
    back = load_scenario(save_scenario(sc, tmp_path / f"s{suffix}"))
    _assert_bit_exact(sc, back)


def test_all_builtins_listed_and_round_trip_every_one(tmp_path):
    for name in bn.list_scenarios():
        sc = bn.load_scenario(name)
        for suffix in (".toml", ".json"):
            _assert_bit_exact(sc, load_scenario(save_scenario(sc, tmp_path / f"{name}{suffix}")))


def test_toml_syntax_error(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('name = "x"\nalpha = = 0.1\n')
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(p)
    assert info.value.field == "file" and str(info.value).startswith("file: ")
    assert "malformed TOML" in str(info.value) and str(p) in str(info.value) and "line 2" in str(info.value)


def test_toml_file_value_fault_names_the_field(tmp_path):
    p = tmp_path / "mixed.toml"
    text = save_scenario(bn.load_scenario("cube3d"), tmp_path / "c.toml").read_text()
    text += '\n[[obstacles]]\nname = "flat"\nvertices = [[0.8, 0.2], [0.9, 0.2], [0.85, 0.3]]\n'
    p.write_text(text)
    with pytest.raises(ValidationError) as info:
        load_scenario(p)
    assert info.value.field == "obstacles[2]" and "2-D" in str(info.value) and "3-D" in str(info.value)


def test_json_syntax_error(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{"name": "x", "alpha": }')
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(p)
    assert info.value.field == "file" and "malformed JSON" in str(info.value) and "line 1" in str(info.value)


def test_not_utf8(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_bytes(b"name = \"\xff\xfe\"\n")
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(p)
    assert info.value.field == "file"


def test_json_top_level_array(tmp_path):
    p = tmp_path / "list.json"
    p.write_text("[1, 2]")
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(p)
    assert info.value.field == "file" and "top level" in str(info.value)


def test_file_errors_name_the_nested_field(tmp_path):
    text = bn.load_scenario("quad").to_dict()
    text["start"]["P"] = [[1e-9, 0.0], [0.0, float("nan")]]
    p = tmp_path / "nan.json"
    p.write_text(json.dumps(text))  # Python's json writes NaN; the loader must still reject it
    with pytest.raises(ValidationError) as info:
        load_scenario(p)
    assert info.value.field == "start.P" and "NaN" in str(info.value)


def test_missing_file_unknown_name_and_directory(tmp_path):
    for arg, field in [(tmp_path / "nope.toml", "file"), ("no-such-builtin", "name"), (tmp_path, "file")]:
        with pytest.raises(ScenarioFileError) as info:
            load_scenario(arg)
        assert info.value.field == field and field in str(info.value)
    with pytest.raises(ScenarioFileError) as info:
        load_scenario("paper_multi")
    assert "paper-multi" in str(info.value)  # lists the built-ins


def test_save_rejects_unknown_suffix_and_unwritable_planner_values(tmp_path):
    sc = bn.load_scenario("quad")
    with pytest.raises(ValidationError) as info:
        save_scenario(sc, tmp_path / "s.yaml")
    assert info.value.field == "path" and ".yaml" in str(info.value)
    odd = sc.with_options(planner={"callback": object()})
    for suffix in (".toml", ".json"):
        with pytest.raises(ValidationError) as info:
            save_scenario(odd, tmp_path / f"odd{suffix}")
        assert info.value.field == "planner"


def test_load_accepts_a_scenario_and_str_paths(tmp_path):
    sc = bn.load_scenario("tutorial")
    assert load_scenario(sc) is sc
    p = save_scenario(sc, tmp_path / "t.toml")
    assert load_scenario(str(p)) == sc


# ------------------------------------------------------------------------ docs
def _doc_blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOCS.read_text(), flags=re.S)


def test_schema_doc_examples_load_and_agree(tmp_path):
    toml_blocks, json_blocks = _doc_blocks("toml"), _doc_blocks("json")
    assert toml_blocks and json_blocks
    (tmp_path / "a.toml").write_text(toml_blocks[0])
    (tmp_path / "a.json").write_text(json_blocks[0])
    a = load_scenario(tmp_path / "a.toml")
    b = load_scenario(tmp_path / "a.json")
    _assert_bit_exact(a, b)
