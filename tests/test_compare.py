"""belief_nlp.comparison (bn.compare): one record per method from one warm start."""

from __future__ import annotations

import json

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.comparison import RECORD_KEYS, compact, compare, records_to_table

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=2)          # K = 10


@pytest.fixture(scope="module")
def records(small):
    sc, path = small
    return compare(sc, path, methods=("ccp", "ipopt"), alpha=1.0)


def test_one_record_per_method(records):
    assert [r["method"] for r in records] == ["ccp", "ipopt"]
    for r in records:
        assert set(r) == set(RECORD_KEYS)
        assert r["status"] == "converged" and r["success"] and r["safe"] and r["error"] is None
        assert r["K"] == 10 and r["alpha"] == 1.0 and r["scenario"] == "paper-multi"
        assert r["cost"] == pytest.approx(r["control"] + 1.0 * r["information"])
        assert r["cost"] < r["initial_cost"]
        assert r["wall_time"] >= r["solver_time"] > 0 and r["iterations"] > 0
        assert r["worst_margin"] >= -1e-6 * 4.61
        assert isinstance(r["path"], bn.BeliefPath) and bn.verify(bn.load_scenario("paper-multi"), r["path"]).safe
        assert r["history"][0]["solver_status"] == "warm_start"
    # the same warm start for both, and the same local optimum (0.5 %)
    assert records[0]["initial_cost"] == records[1]["initial_cost"]
    assert records[1]["cost"] == pytest.approx(records[0]["cost"], rel=5e-3)


def test_errors_are_recorded_and_the_study_goes_on(small):
    sc, path = small
    recs = compare(sc, path, methods=("nope", "ipopt"), max_iter={"ipopt": 3000})
    assert recs[0]["status"] == "error" and not recs[0]["success"] and "nope" in recs[0]["error"]
    assert np.isnan(recs[0]["cost"]) and recs[0]["path"] is None
    assert recs[1]["status"] == "converged"
    table = records_to_table(recs)
    assert "error: nope" in table


def test_infeasible_start_gives_error_records():
    sc = bn.load_scenario("paper-multi")
    # straight through obstacle 5
    x = np.array([[0.15, 0.5], [0.55, 0.25], [0.65, 0.05]])
    path = bn.BeliefPath.from_sensing(x, sc.P0, np.zeros((2, 2, 2)), W=sc.W)
    recs = compare(sc, path)                      # default: every registered method
    assert [r["status"] for r in recs] == ["error"] * len(bn.available_methods())
    assert all("warm start failed" in r["message"] for r in recs)


def test_per_method_limits_and_options(small):
    sc, path = small
    ws = bn.warm_start(sc, path)
    recs = compare(sc, ws, methods=("ccp", "ipopt"), max_iter={"ccp": 2, "ipopt": 3000},
                   method_options={"ipopt": {"formulation": "minors"}})
    assert recs[0]["status"] == "max_iter" and recs[0]["iterations"] == 2
    assert recs[1]["status"] == "converged"
    assert recs[0]["warm_start_time"] == 0.0          # the WarmStart was reused as given
    with pytest.raises(bn.ValidationError):
        compare(sc, ws, K=ws.K + 1)


def test_table_and_compact_records(records):
    table = records_to_table(records)
    lines = table.splitlines()
    assert lines[0].startswith("| method") and "cost" in lines[0] and "wall s" in lines[0]
    assert len(lines) == 2 + len(records)
    assert "ccp" in lines[2] and "ipopt" in lines[3]
    small = [compact(r) for r in records]
    assert all("history" not in r and "path" not in r for r in small)
    back = json.loads(json.dumps(small))
    assert back[1]["method"] == "ipopt"
    # records that differ by seed get a seed column
    seeded = [dict(small[0], seed=0), dict(small[0], seed=1)]
    assert "seed" in records_to_table(seeded).splitlines()[0]
    assert records_to_table([]) == "(no records)"


def test_compare_is_the_function_and_comparison_the_module():
    """`bn.compare` is a function; its module has a name of its own, so
    importing the module never yields the function (or the other way round)."""
    import importlib
    import types

    mod = importlib.import_module("belief_nlp.comparison")
    assert isinstance(mod, types.ModuleType) and callable(bn.compare) and bn.compare is mod.compare
    assert not isinstance(bn.compare, types.ModuleType)
