"""Issue 13, bad input: every reproducer raises our own error, naming the field, fast.

Each case is timed: "typed" is not enough if it takes a minute to get there.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp import _limits
from belief_nlp.errors import ScenarioFileError, ValidationError
from belief_nlp.polytope import Polytope

NESTED = "[" * 100_000 + "]" * 100_000


def raises_fast(fn, field, *words, exc=ValidationError, seconds=2.0):
    """fn() raises ``exc`` with ``.field == field`` (and ``words`` in the message) within ``seconds``."""
    t0 = time.perf_counter()
    with pytest.raises(exc) as info:
        fn()
    elapsed = time.perf_counter() - t0
    err = info.value
    assert err.field == field, str(err)
    for w in words:
        assert w in str(err), f"{w!r} not in {str(err)!r}"
    assert elapsed < seconds, f"took {elapsed:.2f} s"
    return err


@pytest.fixture(scope="module")
def paper():
    return bn.load_scenario("paper-multi")


@pytest.fixture
def base(paper):
    return paper.to_dict()


def regular_polygon(n, r=0.1, centre=(0.5, 0.5)):
    t = np.arange(n) * 2 * np.pi / n
    return np.column_stack([centre[0] + r * np.cos(t), centre[1] + r * np.sin(t)])


# ------------------------------------------------------------ nested / huge files
@pytest.mark.parametrize("suffix, text", [
    (".json", NESTED),
    (".toml", "a = " + NESTED),
    (".json", '{"name": ' + "[" * 40 + "]" * 40 + "}"),   # parses, but deeper than the limit
    (".toml", "a = " + "[" * 40 + "]" * 40),
])
def test_deeply_nested_scenario_file(tmp_path, suffix, text):
    f = tmp_path / f"deep{suffix}"
    f.write_text(text)
    raises_fast(lambda: bn.load_scenario(f), "file", "nested", exc=ScenarioFileError)


@pytest.mark.parametrize("loader", [bn.BeliefPath.load, bn.PlanResult.load])
def test_deeply_nested_path_and_result_files(tmp_path, loader):
    f = tmp_path / "deep.json"
    f.write_text(NESTED)
    raises_fast(lambda: loader(f), "path", "nested", exc=ScenarioFileError)


@pytest.mark.parametrize("text", [NESTED, "[" * 100_000 + "]" * 100_000, '{"x": [1'])
def test_cli_path_file_nested_or_malformed_exits_2_with_one_line(tmp_path, capsys, text):
    """Every bad --path file is bad input: exit 2, one line naming --path, no traceback."""
    from belief_nlp.cli import main

    f = tmp_path / "deep.json"
    f.write_text(text)
    assert main(["smooth", "paper-multi", "--path", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--path" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("suffix, text", [(".json", '{"alpha": ' + "7" * 5000 + "}"),
                                          (".toml", "alpha = " + "7" * 5000)])
def test_5000_digit_integer(tmp_path, suffix, text):
    f = tmp_path / f"big{suffix}"
    f.write_text(text)
    raises_fast(lambda: bn.load_scenario(f), "file", exc=ScenarioFileError)


def test_400_digit_integer_names_the_field(tmp_path, base):
    base["alpha"] = 10 ** 400
    raises_fast(lambda: bn.scenario_from_dict(base), "alpha", "digits", exc=ScenarioFileError)
    f = tmp_path / "p.json"
    f.write_text('{"x": [[' + "9" * 300 + ', 0], [0, 0]], "P": [], "P_prior": [], "S": []}')
    raises_fast(lambda: bn.BeliefPath.load(f), "x[0][0]", "digits", exc=ScenarioFileError)


def test_file_size_limits(tmp_path):
    big = tmp_path / "big.toml"
    with open(big, "wb") as fh:             # sparse: no data written
        fh.truncate(_limits.MAX_SCENARIO_FILE_BYTES + 1)
    raises_fast(lambda: bn.load_scenario(big), "file", "limit", exc=ScenarioFileError)
    huge = tmp_path / "huge.json"
    with open(huge, "wb") as fh:
        fh.truncate(_limits.MAX_DATA_FILE_BYTES + 1)
    raises_fast(lambda: bn.BeliefPath.load(huge), "path", "limit", exc=ScenarioFileError)
    raises_fast(lambda: bn.PlanResult.load(huge), "path", "limit", exc=ScenarioFileError)


# --------------------------------------------------------------- magnitudes
@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["noise"].__setitem__("W", 1e300), "noise.W"),
    (lambda d: d["noise"].__setitem__("W", 1e-30), "noise.W"),
    (lambda d: d["noise"].__setitem__("W_rate", [[1e13, 0], [0, 1e13]]), "noise.W_rate"),
    (lambda d: d["start"].__setitem__("P", 1e300), "start.P"),
    (lambda d: d.__setitem__("domain", {"box": {"lower": [0, 0], "upper": [1e300, 1e300]}}), "domain.box.upper"),
    (lambda d: d.__setitem__("domain", {"box": {"lower": [-1e7, 0], "upper": [1, 1]}}), "domain.box.lower"),
    (lambda d: d.__setitem__("domain", {"A": [[1, 0], [0, 1], [-1, -1]], "b": [1e300, 1, 1]}), "domain.b"),
    (lambda d: d["start"].__setitem__("x", [1e7, 0.5]), "start.x"),
    (lambda d: d["start"].__setitem__("confidence", 1e300), "start.confidence"),
    (lambda d: d["start"].__setitem__("confidence", -1e-300), "start.confidence"),
    (lambda d: d.__setitem__("alpha", 1e300), "alpha"),
    (lambda d: d.__setitem__("chi2", 1e300) or d.pop("confidence"), "chi2"),
    (lambda d: d.__setitem__("horizon", {"K": 10 ** 6}), "horizon.K"),
    (lambda d: d.__setitem__("obstacles", [{"box": {"lower": [0.9, 0.9], "upper": [0.95, 0.95]}}] * 1001),
     "obstacles"),
])
def test_absurd_magnitudes_rejected_at_validation(base, mutate, field):
    mutate(base)
    raises_fast(lambda: bn.scenario_from_dict(base), field)


# ----------------------------------------------------------------- polygons
@pytest.mark.parametrize("n", [1000, 2000, 4000, 20000])
def test_regular_polygons_validate_in_near_linear_time(n):
    t0 = time.perf_counter()
    poly = Polytope.from_vertices(regular_polygon(n))   # the 4000-gon of radius 0.1 is not "collinear"
    assert time.perf_counter() - t0 < 1.0
    assert poly.n_faces == n and poly.contains([0.5, 0.5])


def test_polygon_limits_and_bad_large_polygons_are_fast():
    raises_fast(lambda: Polytope.from_vertices(regular_polygon(_limits.MAX_POLYTOPE_VERTICES + 1)),
                "vertices", "limit", seconds=1.0)
    rng = np.random.default_rng(0)
    raises_fast(lambda: Polytope.from_vertices(rng.uniform(0, 1, (20000, 2))), "vertices", seconds=1.0)
    V = regular_polygon(20000)
    V[[5, 17000]] = V[[17000, 5]]   # a self-intersecting order of a convex set
    raises_fast(lambda: Polytope.from_vertices(V), "vertices", seconds=1.0)
    V = regular_polygon(20000)
    V[12345] = V[3]                  # a repeated vertex, far apart in the list
    raises_fast(lambda: Polytope.from_vertices(V), "vertices", "repeated vertex", "3 and 12345", seconds=1.0)


def test_many_halfspaces():
    n = 100_000
    th = np.arange(n) * 2 * np.pi / n
    A = np.column_stack([np.cos(th), np.sin(th)])
    raises_fast(lambda: Polytope.from_halfspaces(A, np.ones(n), field_name="domain"), "domain.A", "limit",
                seconds=1.0)
    m = 2000
    th = np.arange(m) * 2 * np.pi / m
    t0 = time.perf_counter()
    poly = Polytope.from_halfspaces(np.column_stack([np.cos(th), np.sin(th)]), np.ones(m))
    assert time.perf_counter() - t0 < 2.0
    assert poly.vertices.shape == (m, 2)
    assert np.allclose(np.linalg.norm(poly.vertices, axis=1), 1 / np.cos(np.pi / m))


def test_box_dimension_limit():
    raises_fast(lambda: Polytope.box(np.zeros(40), np.ones(40)), "box", "limit", seconds=0.5)


# ------------------------------------------------------------------ loaders
def test_belief_path_load_of_a_non_zip_npz(tmp_path):
    f = tmp_path / "junk.npz"
    f.write_bytes(b"this is not a zip archive")
    raises_fast(lambda: bn.BeliefPath.load(f), "path", "NPZ", exc=ScenarioFileError)
    raises_fast(lambda: bn.PlanResult.load(f), "path", "NPZ", exc=ScenarioFileError)


def test_belief_path_load_of_an_npz_with_text_arrays(tmp_path):
    f = tmp_path / "text.npz"
    np.savez(f, x=np.array([["a", "b"], ["c", "d"]]), P=np.zeros((2, 2, 2)), P_prior=np.zeros((2, 2, 2)),
             S=np.zeros((2, 2, 2)), noise=np.array("per_step"), meta=np.array("{}"))
    raises_fast(lambda: bn.BeliefPath.load(f), "path.x")
    g = tmp_path / "meta.npz"
    np.savez(g, x=np.zeros((2, 2)), P=np.zeros((2, 2, 2)), P_prior=np.zeros((2, 2, 2)), S=np.zeros((2, 2, 2)),
             noise=np.array("per_step"), meta=np.array("[" * 50 + "]" * 50))
    raises_fast(lambda: bn.BeliefPath.load(g), "path.meta", "nested", exc=ScenarioFileError)


def test_from_covariances_with_a_singular_p(paper):
    x = [[0.15, 0.5], [0.2, 0.5], [0.25, 0.5]]
    P = np.array([paper.P0, 1e-3 * np.eye(2), np.zeros((2, 2))])
    raises_fast(lambda: bn.BeliefPath.from_covariances(x, P, W=paper.W), "P", "P_2")


def test_with_options_unknown_keyword(paper):
    raises_fast(lambda: paper.with_options(bogus=1), "bogus", "known")


def test_scenario_names_the_os_refuses():
    raises_fast(lambda: bn.load_scenario("x" * 5000), "name", "limit", exc=ScenarioFileError)
    raises_fast(lambda: bn.load_scenario("x" * 300), "name", "unknown scenario", exc=ScenarioFileError)
    raises_fast(lambda: bn.load_scenario("bad\0name.toml"), "file", exc=ScenarioFileError)
    raises_fast(lambda: bn.load_scenario(None), "scenario")


def test_writing_to_a_missing_folder(tmp_path, paper, paper_multi_path):
    raises_fast(lambda: bn.save_scenario(paper, "/nonexistent/x.json"), "file", exc=ScenarioFileError)
    _, path = paper_multi_path
    raises_fast(lambda: path.save(tmp_path / "no" / "p.npz"), "path", exc=ScenarioFileError)


@pytest.mark.parametrize("content, field", [
    ("{not json", "path"),
    ('{"format": "other"}', "result"),
    ('{"format": "belief_nlp.PlanResult/1"}', "result.success"),
    ('{"format": "belief_nlp.PlanResult/1", "success": true, "message": "", "cost": "lots", "travel": 1,'
     ' "information": 1, "alpha": 0.1, "metric": "entropy", "info_unit": "nats", "noise": "per_step",'
     ' "cost_history": []}', "result"),
    ('{"format": "belief_nlp.PlanResult/1", "success": true, "message": "", "cost": 1, "travel": 1,'
     ' "information": 1, "alpha": 0.1, "metric": "entropy", "info_unit": "nats", "noise": "per_step",'
     ' "cost_history": [], "tree": {"x": [[0, 0]], "P": [[[1, 0], [0, 1]]], "parent": [5], "cost": [0],'
     ' "live": [true], "goal": [false]}}', "tree.parent"),
])
def test_plan_result_load_errors_stay_typed(tmp_path, content, field):
    f = tmp_path / "r.json"
    f.write_text(content)
    raises_fast(lambda: bn.PlanResult.load(f), field)
    raises_fast(lambda: bn.PlanResult.load(tmp_path / "missing.json"), "path", "no such file",
                exc=ScenarioFileError)


def test_path_file_with_a_nan_names_the_field(tmp_path, paper_multi_path):
    _, path = paper_multi_path
    d = path.to_dict()
    d["P"][3][0][0] = float("nan")
    f = tmp_path / "nan.json"
    f.write_text(json.dumps(d))    # Python's json writes NaN
    raises_fast(lambda: bn.BeliefPath.load(f), "path.P", "NaN")


@pytest.mark.parametrize("kwargs, field", [
    (dict(alpha=10 ** 400), "alpha"), (dict(alpha=float("nan")), "alpha"), (dict(alpha=1e300), "alpha"),
    (dict(n_nodes=10 ** 9), "n_nodes"), (dict(eig_range=(1e-9, 10 ** 400)), "eig_range"),
    (dict(eig_range=(1e-9, 1e300)), "eig_range"), (dict(time_limit=float("nan")), "time_limit"),
    (dict(max_radius=float("inf")), "max_radius"), (dict(bogus=1), "bogus"),
])
def test_planner_arguments(paper, kwargs, field):
    raises_fast(lambda: bn.plan(paper, **kwargs), field, seconds=0.5)


def test_a_plans_risk_record_with_a_number_no_float_holds_is_refused():
    """A plan file's risk record read back (PlanResult.load checks it): a
    400-digit budget (JSON holds it) is our error naming the field, not an
    OverflowError from math.isfinite."""
    from belief_nlp.planner.result import _check_risk

    record = {"budget": 10 ** 400, "collision_chi2": 4.6, "target_chi2": 4.6, "bound": None, "rounds": []}
    raises_fast(lambda: _check_risk(record), "risk.budget", "finite number")
