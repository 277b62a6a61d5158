"""Studies: TOML form, expansion and keys, process pool vs a real Dask LocalCluster,
resume, failures, fallback, reproduction, report and CLI (tiny settings)."""

from __future__ import annotations

import json
import math

import pytest

import belief_nlp as bn
from belief_nlp.study import (Limits, Study, TIMING_COLUMNS, case_from_dict, load_study, reproduce, run_case, run_study,
                              write_report)
from belief_nlp.study.analysis import method_table, performance_profile, shifted_geometric_mean
from belief_nlp.study.runner import rows_equal

TINY = """
[study]
name = "tiny"
scenarios = ["paper-multi", "random-polygons@1"]
seeds = [0]
alpha = [0.1]
K = [12, 2]                      # K = 2 is below the plans' edge counts: one step per edge instead
methods = ["none", "ccp", "ipopt"]
case_timeout = 300

[planner]
n_nodes = 100

[solver.ccp]
max_iter = 2

[solver.ipopt]
max_iter = 10
"""

ISSUE_FORM = """
[study]
name = "smoke"
scenarios = ["paper-multi", "random-polygons:2"]   # built-in names, scenario files, or family:count
seeds = [0, 1]
alpha = [0.1, 1.0]
K = [20]
methods = ["ccp", "ipopt"]

[planner]
n_nodes = 300
"""


@pytest.fixture(scope="module")
def tiny_toml(tmp_path_factory):
    f = tmp_path_factory.mktemp("study") / "tiny.toml"
    f.write_text(TINY)
    return f


@pytest.fixture(scope="module")
def pool_dir(tiny_toml, tmp_path_factory):
    out = tmp_path_factory.mktemp("pool")
    summary = run_study(tiny_toml, out, workers=2, progress=False)
    assert summary.cases == 4 and summary.ran == 4 and summary.rows == 12
    return out


def _sorted_rows(directory):
    df = bn.load_records(directory)
    return sorted(df.to_dict("records"), key=lambda r: (r["case_key"], r["method"]))


def test_issue_form_expands(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text(ISSUE_FORM)
    st = load_study(f)
    cases = list(st.cases())
    assert len(cases) == 3 * 2 * 2 * 1          # scenarios (paper-multi + 2 maps) x seeds x alpha x K
    assert len({c.key for c in cases}) == len(cases)
    assert [c.key for c in load_study(f).cases()] == [c.key for c in cases]       # stable keys
    assert {c.scenario.label for c in cases} == {"paper-multi", "random-polygons-0", "random-polygons-1"}
    assert all([m.label for m in c.methods] == ["ccp", "ipopt"] for c in cases)
    assert Study.from_dict(st.to_dict()).to_dict() == st.to_dict()
    c = cases[0]
    assert case_from_dict(json.loads(json.dumps(c.to_dict()))).key == c.key


def test_grids_arms_and_variants():
    st = Study(name="g", scenarios=["paper-multi"], seeds=[0], alpha=[0.1], K=[20], methods=["none"],
               planner={"n_nodes": [250, 500], "max_radius": 0.3},
               solver={"ccp": {"max_iter": [5, 10], "tol": 1e-3}},
               arms=[{"name": "raw", "planner": {"n_nodes": [250, 1000]}, "methods": ["none"]},
                     {"name": "smoothed", "planner": {"n_nodes": [250]}, "methods": ["none", "ccp"]}])
    cases = list(st.cases())
    assert sorted(c.planner["n_nodes"] for c in cases) == [250, 250, 1000]     # the grid of each arm
    sm = [c for c in cases if c.arm == "smoothed"][0]
    assert [m.label for m in sm.methods] == ["none", "ccp[max_iter=5]", "ccp[max_iter=10]"]
    assert sm.methods[1].options == {"max_iter": 5, "tol": 1e-3}
    with pytest.raises(bn.ValidationError):
        Study.from_dict({"study": {"name": "x", "bogus": 1}})
    with pytest.raises(bn.ValidationError, match="scenarios"):
        list(Study(scenarios=["no-such-scenario"]).cases())


def test_pool_records_columns_and_fallback(pool_dir):
    df = bn.load_records(pool_dir)
    assert len(df) == 12
    for col in ("scenario", "seed", "alpha", "K", "method", "status", "success", "cost", "safe", "wall_time",
                "planner_cost", "warm_start_cost", "control", "information", "iterations", "plan_time",
                "warm_start_time", "build_time", "solve_time", "stats", "min_margin", "error",
                "belief_nlp_version", "solver_version", "case", "K_used", "warm_start_fallback"):
        assert col in df.columns, col
    ok = df[df["status"] != "plan_failed"]
    assert len(ok) >= 6
    assert ok["safe"].all()
    # the IG-RRT* backend that ran: numba's attempts round apart from numpy's, so a study says which
    from belief_nlp.planner import compiled
    assert (df["planner_backend"] == ("numba" if compiled.available() else "numpy")).all()
    # every method of a case starts from the same warm start
    assert (ok.groupby("case_key")["warm_start_cost"].nunique() == 1).all()
    assert (ok["cost"] <= ok["warm_start_cost"] * (1 + 1e-9)).all()
    small = ok[ok["K"] == 2]
    assert len(small) and small["warm_start_fallback"].all() and (small["K_used"] > 2).all()
    assert small["fallback_reason"].str.contains("K").all()
    big = ok[ok["K"] == 12]
    assert not big["warm_start_fallback"].any() and (big["K_used"] == 12).all()
    ccp = ok[ok["method"] == "ccp"]
    assert (ccp["solver"] == "CLARABEL").all() and (ccp["solver_version"] != "").all()
    assert all(json.loads(s) for s in ccp["stats"])


def test_dask_local_cluster_gives_the_same_records(tiny_toml, pool_dir, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        summary = run_study(tiny_toml, tmp_path, dask=client, progress=False)
    assert summary.executor == "dask" and summary.ran == 4
    a, b = _sorted_rows(pool_dir), _sorted_rows(tmp_path)
    assert len(a) == len(b) == 12
    for ra, rb in zip(a, b):
        assert rows_equal(ra, rb), {k: (ra.get(k), rb.get(k)) for k in ra
                                    if k not in TIMING_COLUMNS and ra.get(k) != rb.get(k)}


def test_resume_skips_finished_cases(tiny_toml, pool_dir):
    before = (pool_dir / "records.jsonl").read_text()
    summary = run_study(tiny_toml, pool_dir, workers=1, progress=False)
    assert summary.skipped == 4 and summary.ran == 0 and summary.rows == 0
    assert (pool_dir / "records.jsonl").read_text() == before


def test_row_reproduces_its_case(pool_dir):
    df = bn.load_records(pool_dir)
    row = df[(df["method"] == "ccp") & (df["status"] != "plan_failed")].iloc[0]
    again = {r["method"]: r for r in reproduce(row)}["ccp"]
    assert rows_equal({k: row[k] for k in again}, again, rtol=1e-7)


def test_builtin_smoke_study_runs_every_method_to_convergence():
    """The smoke study caps no method (a cap would give max_iter rows that read
    as failures); one of its cases, run here, plans and both smoothers converge
    to the same optimum (the whole study: docs/studies.md)."""
    st = load_study("smoke")
    cases = list(st.cases())
    assert len(cases) == 12 and "to convergence" in st.description
    assert all("max_iter" not in v.options for c in cases for v in c.methods)
    case = next(c for c in cases if (c.scenario.label, c.seed, c.alpha) == ("random-polygons-0", 1, 1.0))
    rows = {r["method"]: r for r in run_case(case)}
    assert rows["none"]["status"] == "warm_start"
    for m in ("ccp", "ipopt"):
        assert rows[m]["status"] == "converged" and rows[m]["safe"] and rows[m]["cost"] < rows["none"]["cost"]
    assert rows["ccp"]["cost"] == pytest.approx(rows["ipopt"]["cost"], rel=1e-3)


# the case timeout's alarm may land inside a weakref callback, where Python prints and
# drops the exception; the runner's deadline raises it again (study/runner.py, _deadline)
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_failures_are_recorded_and_the_study_goes_on(tmp_path):
    st = Study(name="bad", scenarios=["paper-multi"], seeds=[0], alpha=[0.1], K=[12],
               methods=["none", "no-such-method"], planner={"n_nodes": 100})
    rows = run_case(next(st.cases()))
    by = {r["method"]: r for r in rows}
    assert by["none"]["status"] == "warm_start" and by["none"]["safe"]
    assert by["no-such-method"]["status"] == "error" and "no-such-method" in by["no-such-method"]["error"]
    # a case that runs out of time records "timeout" for what is left
    slow = Study(name="slow", scenarios=["paper-multi"], seeds=[0], alpha=[0.1], K=[12], methods=["ccp"],
                 planner={"n_nodes": 3000}, limits=Limits(case_timeout=0.01))    # 0.3 s: a fast host finished
    rows = run_case(next(slow.cases()))
    assert [r["status"] for r in rows] == ["timeout"] and "case_timeout" in rows[0]["error"]
    # through the executor: a bad planner option fails its case, the others run
    mixed = Study(name="mixed", scenarios=["paper-multi"], seeds=[0], alpha=[0.1], K=[12], methods=["none"],
                  planner={"n_nodes": 100, "max_radius": [0.3, -1.0]})
    summary = run_study(mixed, tmp_path, workers=1, progress=False)
    assert summary.ran == 2 and summary.failed_rows == 1
    df = bn.load_records(tmp_path)
    assert set(df["status"]) == {"warm_start", "error"}


def test_montecarlo_metric_in_rows():
    st = Study(name="mc", scenarios=["paper-multi"], seeds=[0], alpha=[0.1], K=[12], methods=["none"],
               planner={"n_nodes": 100}, limits=Limits(montecarlo=500))
    (row,) = run_case(next(st.cases()))
    assert row["mc_runs"] == 500 and 0 <= row["mc_rate"] <= 1
    assert row["mc_ci_low"] <= row["mc_rate"] <= row["mc_ci_high"]
    assert row["nominal_rate"] == pytest.approx(0.1)


def test_analysis_numbers():
    import pandas as pd

    assert shifted_geometric_mean([1.0, 3.0], shift=1.0) == pytest.approx(math.sqrt(2 * 4) - 1)
    rows = []
    for case, (ta, ca, tb, cb) in enumerate([(1.0, 2.0, 2.0, 1.0), (1.0, 1.0, 4.0, 1.0), (1.0, 3.0, 1.0, 1.5)]):
        for m, t, c in (("a", ta, ca), ("b", tb, cb)):
            rows.append({"case_key": str(case), "method": m, "wall_time": t, "cost": c, "safe": True,
                         "status": "converged", "iterations": 1})
    df = pd.DataFrame(rows)
    tab = method_table(df).set_index("method")
    assert tab.loc["b", "best_share"] == pytest.approx(1.0)
    assert tab.loc["a", "cost_ratio_gm"] == pytest.approx((2.0 * 1.0 * 2.0) ** (1 / 3))
    taus, prof = performance_profile(df, "wall_time", taus=[1.0, 2.0, 4.0])
    assert list(prof["a"]) == [1.0, 1.0, 1.0] and list(prof["b"]) == pytest.approx([1 / 3, 2 / 3, 1.0])


def test_report_and_cli(tiny_toml, pool_dir, tmp_path, capsys):
    from belief_nlp.cli import main

    path = write_report(pool_dir)
    text = path.read_text()
    assert "| method |" in text and "ccp" in text and "profile_time.png" in text
    # the tiny study caps CCP at 2 and IPOPT at 10: the report says what iters count and which rows hit a cap
    assert "iters = the smoother's iterations in total" in text
    capped = bn.load_records(pool_dir)["status"].eq("max_iter").sum()
    assert capped > 0 and f"{capped} row(s) stopped at their iteration limit" in text
    assert (pool_dir / "profile_cost.png").exists() and (pool_dir / "cost_vs_time.png").exists()
    out = tmp_path / "cli"
    assert main(["study", "run", str(tiny_toml), "--out", str(out), "--workers", "1", "--limit", "1", "-q"]) == 0
    assert len(bn.load_records(out)) == 3
    assert main(["study", "report", str(out), "-q"]) == 0 and (out / "report.md").exists()
    assert main(["study", "report", str(tmp_path / "nothing")]) == 2
    assert main(["study", "list"]) == 0
    assert "thesis" in capsys.readouterr().out


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_case_timeout_swallowed_in_a_destructor_still_ends_the_case():
    """Python prints and drops an exception raised inside a destructor or a
    weakref callback; a case timeout that lands there (seen in CI: WeakSet._remove)
    must still end the case."""
    import time

    from belief_nlp.study.runner import CaseTimeout, _deadline

    class Slow:
        def __del__(self):
            time.sleep(0.05)          # the alarm fires in here and is swallowed

    with pytest.raises(CaseTimeout, match="case_timeout of 0.01 s"):
        with _deadline(0.01):
            obj = Slow()
            del obj                   # then the case would end normally
