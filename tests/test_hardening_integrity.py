"""Issue 13, data integrity and verify(): read-only arrays, non-finite data,
NaN-safe verdicts, argument checks, names and results accepted, short reprs,
results that reload equal, and the packaging files."""

from __future__ import annotations

import dataclasses
import importlib
import time
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.polytope import Polytope

ROOT = Path(__file__).resolve().parents[1]
verify_module = importlib.import_module("belief_nlp.verify")   # bn.verify is the function


@pytest.fixture(scope="module")
def paper():
    return bn.load_scenario("paper-multi")


@pytest.fixture(scope="module")
def straight(paper):
    """The issue's reproducer: start to target in one straight, colliding step."""
    return bn.BeliefPath.from_sensing([[0.15, 0.5], [0.65, 0.05]], paper.P0, np.zeros((1, 2, 2)), W=paper.W)


@pytest.fixture(scope="module")
def planned():
    return bn.plan("paper-multi", n_nodes=150, seed=1)


def field_of(fn):
    with pytest.raises(ValidationError) as info:
        fn()
    return info.value.field


# --------------------------------------------------------------- read-only
def test_path_arrays_are_read_only_and_private(paper, straight):
    assert not bn.verify(paper, straight).safe
    for name in ("x", "P", "P_prior", "S"):
        arr = getattr(straight, name)
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[...] = np.nan
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(straight, name, np.full_like(arr, np.nan))
    with pytest.raises(dataclasses.FrozenInstanceError):
        straight.noise = "per_metre"
    assert not bn.verify(paper, straight).safe
    x = np.array([[0.15, 0.5], [0.2, 0.5]])
    p = bn.BeliefPath.from_sensing(x, paper.P0, np.zeros((1, 2, 2)), W=paper.W)
    x[1] = np.nan                                        # the caller's array, not the path's
    assert np.all(np.isfinite(p.x))
    q = dataclasses.replace(p, meta={"note": "copies are built, not edited"})
    assert q == dataclasses.replace(p, meta={"note": "copies are built, not edited"})


def test_scenario_and_polytope_arrays_are_read_only(paper):
    for arr in (paper.x0, paper.P0, paper.W, paper.W_rate, paper.domain.A, paper.domain.b,
                paper.obstacles[0].vertices, paper.walls[0].A):
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr.flat[0] = 1.0
    mine = {"max_radius": 0.3}
    sc = paper.with_options(planner=mine)
    mine["max_radius"] = -1.0
    assert sc.planner["max_radius"] == 0.3


def test_result_and_report_arrays_are_read_only(paper, planned):
    assert not planned.cost_history.flags.writeable
    assert not planned.tree.x.flags.writeable and not planned.tree.parent.flags.writeable
    rep = bn.verify(paper, planned.path)
    for arr in (rep.transition_margins, rep.target_margins_m, rep.kalman_residual):
        assert not arr.flags.writeable


# ---------------------------------------------------------------- non-finite
def test_non_finite_data_is_rejected_naming_the_field(paper, straight):
    nan2 = np.full((2, 2), np.nan)
    assert field_of(lambda: bn.BeliefPath(nan2, straight.P, straight.P_prior, straight.S)) == "path.x"
    bad_P = np.array(straight.P)
    bad_P[1, 0, 0] = np.inf
    assert field_of(lambda: bn.BeliefPath(straight.x, bad_P, straight.P_prior, straight.S)) == "path.P"
    assert field_of(lambda: bn.BeliefPath.from_sensing(straight.x, nan2, np.zeros((1, 2, 2)), W=paper.W)) == "P0"
    assert field_of(lambda: bn.BeliefPath.from_sensing(straight.x, paper.P0, np.full((1, 2, 2), np.nan),
                                                       W=paper.W)) == "S"
    assert field_of(lambda: bn.BeliefPath.from_sensing(straight.x, paper.P0, np.zeros((1, 2, 2)), W=nan2)) == "W"
    assert field_of(lambda: bn.BeliefPath.from_covariances(straight.x, straight.P, W_rate=nan2,
                                                           noise="per_metre")) == "W_rate"
    assert field_of(lambda: paper.with_options(x0=[np.nan, 0.5])) == "start.x"
    assert field_of(lambda: paper.with_options(alpha=float("inf"))) == "alpha"
    assert field_of(lambda: Polytope([[1.0, 0.0]], [np.nan])) == "polytope.b"
    assert field_of(lambda: paper.target.contains([np.nan, 0.0])) == "y"
    for cost in (straight.steering_cost, straight.planner_cost, straight.cost_breakdown):
        assert field_of(lambda: cost(float("nan"))) == "alpha"


# -------------------------------------------------------------------- verify
def test_a_path_full_of_nan_is_never_safe(paper, straight):
    sneaky = bn.BeliefPath(straight.x, straight.P, straight.P_prior, straight.S)
    for name in ("x", "P"):
        arr = getattr(sneaky, name)
        arr.flags.writeable = True      # deliberately around the protection
        arr[...] = np.nan
    rep = bn.verify(paper, sneaky)
    assert not rep.safe and not rep
    assert any("NaN" in p for p in rep.problems)
    huge = bn.BeliefPath(straight.x * 1e200, straight.P, straight.P_prior, straight.S)
    assert not bn.verify(paper, huge).safe


def test_nan_margins_fail_instead_of_passing(paper, planned, monkeypatch):
    path = planned.path
    assert bn.verify(paper, path).safe
    real = verify_module._sqdist

    def nan_for_obstacle_3(x, P, poly, **kw):
        out = real(x, P, poly, **kw)
        return np.full_like(out, np.nan) if poly.name == "obstacle 3" else out

    monkeypatch.setattr(verify_module, "_sqdist", nan_for_obstacle_3)
    rep = bn.verify(paper, path)
    assert not rep.safe and rep.min_margin == -np.inf and "obstacle 3" in rep.worst
    assert any("cannot be decided" in p for p in rep.problems)


@pytest.mark.parametrize("kwargs, field", [
    (dict(tol=float("nan")), "tol"), (dict(tol=float("inf")), "tol"), (dict(tol=-1e-9), "tol"),
    (dict(tol=1.0), "tol"), (dict(tol="0.1"), "tol"), (dict(tol=10 ** 400), "tol"),
    (dict(n_samples="x"), "n_samples"), (dict(n_samples=10 ** 9), "n_samples"), (dict(n_samples=1), "n_samples"),
    (dict(n_samples=True), "n_samples"), (dict(n_samples=50.0), "n_samples"), (dict(n_refine=10 ** 9), "n_refine"),
])
def test_verify_arguments(paper, straight, kwargs, field):
    t0 = time.perf_counter()
    assert field_of(lambda: bn.verify(paper, straight, **kwargs)) == field
    assert time.perf_counter() - t0 < 0.5
    assert bn.verify(paper, straight, tol=0.5).tol == 0.5   # within the range, still reported


def test_verify_takes_names_and_results(paper, planned):
    by_object = bn.verify(paper, planned.path)
    by_name = bn.verify("paper-multi", planned)
    assert by_name.safe == by_object.safe and by_name.min_margin == by_object.min_margin

    class Holder:                            # anything with a .path, e.g. a SmoothResult
        path = planned.path

    assert bn.verify(paper, Holder()).safe
    failed = dataclasses.replace(planned, path=None, message="no path")
    assert field_of(lambda: bn.verify(paper, failed)) == "path"
    assert field_of(lambda: bn.verify(paper, "not a path")) == "path"
    assert field_of(lambda: bn.verify(3.5, planned)) == "scenario"
    assert field_of(lambda: bn.verify("cube3d", planned)) == "scenario"   # the named scenario does not fit


# ------------------------------------------------------------ small things
def test_report_repr_is_short(paper, straight, planned):
    bad = repr(bn.verify(paper, straight))
    assert len(bad) < 500 and "safe=False" in bad and "min_margin=" in bad and "obstacle" in bad
    assert "array(" not in bad
    good = repr(bn.verify(paper, planned))
    assert "safe=True" in good and "problems=0" in good and len(good) < 200


def test_plan_results_reload_equal(tmp_path, planned):
    failed = bn.plan("paper-multi", n_nodes=3, seed=0)
    assert not failed.success and np.isnan(failed.travel)
    for res in (planned, failed):
        for suffix in (".json", ".npz"):
            back = bn.PlanResult.load(res.save(tmp_path / f"r{suffix}"))
            assert back == res and not back != res
    assert dataclasses.replace(planned, seed=99) != planned
    assert field_of(lambda: planned.cost_in_authors_units(float("inf"))) == "alpha"
    assert planned != "a result"


def test_path_equality_is_nan_aware_in_meta(straight):
    a = dataclasses.replace(straight, meta={"cost": float("nan"), "runs": [1, float("nan")]})
    b = dataclasses.replace(straight, meta={"cost": float("nan"), "runs": [1, float("nan")]})
    assert a == b
    assert a != dataclasses.replace(straight, meta={"cost": 1.0, "runs": [1, float("nan")]})


def test_packaging_files():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "belief_nlp developers" in text
    assert resources.files("belief_nlp").joinpath("py.typed").is_file()
    assert '"belief_nlp" = ["py.typed"]' in (ROOT / "pyproject.toml").read_text()
    assert "notebooks/*_out/" in (ROOT / ".gitignore").read_text().splitlines()


def test_ci_runs_the_readmes_commands():
    """.ci/run installs with the README's first command and tests with its
    second, word for word (the test command's plugins come with the test extra)."""
    readme = (ROOT / "README.md").read_text()
    block = readme.split("```bash\n", 1)[1].split("```", 1)[0].splitlines()
    install, test = block[0].split(" && ")[0], block[1]
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert install in ci and test in ci, (install, test)
    if " -n " in f" {test} ":
        assert '"pytest-xdist' in (ROOT / "pyproject.toml").read_text()
