"""Issue 13, a small fuzz suite: scenario dicts and files, path files and
verify() arguments. Every case ends in our error type or a valid result,
never another exception, and within a time bound.

CI runs it derandomised (the "ci" profile of conftest.py); local runs explore.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import belief_nlp as bn
from belief_nlp.errors import ValidationError

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                      HealthCheck.function_scoped_fixture])
CASE_SECONDS = 5.0

PAPER = bn.load_scenario("paper-multi")
BASE = PAPER.to_dict()
PATH = bn.BeliefPath.from_sensing([[0.15, 0.5], [0.15, 0.8], [0.45, 0.8]], PAPER.P0,
                                  np.broadcast_to(1e4 * np.eye(2), (2, 2, 2)), W=PAPER.W)

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-320, 1e-30, 1e300, -1e300, 1e7, 0.5, 1.0]),
    st.integers(min_value=-(10 ** 30), max_value=10 ** 30),
    st.sampled_from([10 ** 400, -(10 ** 400), True, False]),
)
scalars = st.one_of(numbers, st.none(), st.text(max_size=8))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=5), inner, max_size=3)),
                      max_leaves=12)


def _paths(tree, prefix=()):
    """Every (key path) inside a JSON-like tree."""
    yield prefix
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield from _paths(v, prefix + (i,))


SCENARIO_SLOTS = [p for p in _paths(BASE) if p]
PATH_SLOTS = [p for p in _paths(PATH.to_dict()) if p and p[0] != "meta"]


def _replace(tree, where, value):
    tree = json.loads(json.dumps(tree))
    node = tree
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    return tree


def _ours_or_valid(fn, kind):
    """Run fn(); a result of ``kind`` or a ValidationError pass, anything else fails."""
    t0 = time.perf_counter()
    try:
        out = fn()
    except ValidationError as err:
        assert err.field is not None and str(err)
        out = None
    elapsed = time.perf_counter() - t0
    assert elapsed < CASE_SECONDS, f"{elapsed:.2f} s"
    assert out is None or isinstance(out, kind)
    return out


@FUZZ
@given(where=st.sampled_from(SCENARIO_SLOTS), value=values)
def test_fuzz_scenario_dicts(where, value):
    sc = _ours_or_valid(lambda: bn.scenario_from_dict(_replace(BASE, where, value)), bn.Scenario)
    if sc is not None:   # a valid scenario is fully usable: finite chi2, a round trip
        assert math.isfinite(sc.chi2) and sc == bn.scenario_from_dict(sc.to_dict())


@FUZZ
@given(text=st.one_of(st.text(max_size=200), st.sampled_from([
    "[" * 3000 + "]" * 3000, "a = " + "{b = " * 500 + "1" + "}" * 500, "alpha = 1" + "0" * 5000,
    json.dumps(BASE), json.dumps(BASE).replace("0.9", "NaN"), json.dumps(BASE)[:-7]])),
       suffix=st.sampled_from([".json", ".toml", ".txt"]))
def test_fuzz_scenario_files(tmp_path, text, suffix):
    f = tmp_path / f"s{suffix}"
    f.write_text(text, encoding="utf-8", errors="surrogatepass")
    _ours_or_valid(lambda: bn.load_scenario(f), bn.Scenario)


@FUZZ
@given(where=st.sampled_from(PATH_SLOTS), value=values, suffix=st.sampled_from([".json", ".npz"]))
def test_fuzz_path_files(tmp_path, where, value, suffix):
    data = _replace(PATH.to_dict(), where, value)
    f = tmp_path / f"p{suffix}"
    if suffix == ".json":
        f.write_text(json.dumps(data))
    else:
        arrays = {}
        for k in ("x", "P", "P_prior", "S"):
            try:
                arrays[k] = np.asarray(data[k])
            except (ValueError, TypeError, OverflowError):
                arrays[k] = np.asarray(str(data[k]))
        if any(a.dtype == object for a in arrays.values()):
            return
        np.savez(f, **arrays, noise=np.asarray(str(data["noise"])), meta=np.asarray(json.dumps(data["meta"])))
    path = _ours_or_valid(lambda: bn.BeliefPath.load(f), bn.BeliefPath)
    if path is not None:
        _ours_or_valid(lambda: bn.verify(PAPER, path), bn.VerificationReport)


@FUZZ
@given(data=st.binary(max_size=300))
def test_fuzz_raw_bytes_as_npz(tmp_path, data):
    f = tmp_path / "p.npz"
    f.write_bytes(b"PK\x03\x04" + data if data[:1] == b"\x00" else data)
    _ours_or_valid(lambda: bn.BeliefPath.load(f), bn.BeliefPath)
    _ours_or_valid(lambda: bn.PlanResult.load(f), bn.PlanResult)


@FUZZ
@given(n_samples=st.one_of(numbers, st.text(max_size=3)), tol=st.one_of(numbers, st.none()))
def test_fuzz_verify_arguments(n_samples, tol):
    rep = _ours_or_valid(lambda: bn.verify(PAPER, PATH, n_samples=n_samples, tol=tol), bn.VerificationReport)
    if rep is not None:
        assert 2 <= n_samples <= 10_001 and 0 <= tol < 1
        assert rep.safe == (not rep.problems)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0, 0.0, 1e300])
def test_every_path_array_slot_rejects_or_reports(value):
    """Each entry of each path array set to a bad value: rejected, or verified unsafe / consistent."""
    for name in ("x", "P", "P_prior", "S"):
        arr = np.array(getattr(PATH, name))
        arr.flat[arr.size // 2] = value
        fields = {k: getattr(PATH, k) for k in ("x", "P", "P_prior", "S")}
        fields[name] = arr
        path = _ours_or_valid(lambda: bn.BeliefPath(**fields), bn.BeliefPath)
        if path is not None:
            rep = bn.verify(PAPER, path)
            assert rep.safe == (not rep.problems)
