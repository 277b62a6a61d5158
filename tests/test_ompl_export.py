"""Study records as an OMPL benchmark database, opened by OMPL's own tools.

Three readers, independent of the writer: a minimal reader of the schema
written here from OMPL's documentation (benchmark.md, "The benchmark
database schema"), Planner Arena's loader and plots (``plannerarena`` from
PyPI, the tool that opens these databases) and ``ompl.tools.computeViews``
(from the ``ompl`` wheel). The last two skip when not installed; the test
extra installs both.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sqlite3

import pytest

import belief_nlp as bn
from belief_nlp.cli import main
from belief_nlp.study import load_study, run_study

STUDY = {"study": {"name": "export", "scenarios": ["paper-multi"], "seeds": [0, 1], "alpha": [0.1, 1.0],
                   "K": [0], "methods": ["none", "ccp"], "case_timeout": 300},
         "planner": {"n_nodes": 400, "noise": "per_step"},
         "solver": {"ccp": {"max_iter": 2}}}

STANDARD = ["id", "name", "totaltime", "timelimit", "memorylimit", "runcount", "version", "hostname", "cpuinfo",
            "date", "seed", "setup"]


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    run_study(load_study(STUDY), out, workers=1, progress=False)
    return out


@pytest.fixture(scope="module")
def db(study_dir, tmp_path_factory):
    return bn.export_ompl_benchmark(study_dir, tmp_path_factory.mktemp("db") / "results.db")


def _columns(conn, table):
    return [r[1] for r in conn.execute(f"PRAGMA table_info({table})")]


def test_schema_and_contents_match_the_records(study_dir, db):
    rows = list(bn.study.records.iter_records(study_dir))
    conn = sqlite3.connect(db)
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"experiments", "plannerConfigs", "enums", "runs", "progress"} <= tables
    assert _columns(conn, "experiments")[:12] == STANDARD and _columns(conn, "experiments")[12:] == ["alpha", "K"]
    assert _columns(conn, "runs")[:3] == ["id", "experimentid", "plannerid"]
    assert _columns(conn, "progress")[:2] == ["runid", "time"]
    # one experiment per (scenario, alpha, K); one run per record, joined back by seed and configuration
    exps = conn.execute("SELECT id, name, alpha, K, runcount, version FROM experiments").fetchall()
    assert sorted((e[1], e[2]) for e in exps) == [("paper-multi", 0.1), ("paper-multi", 1.0)]
    assert all(e[4] == 2 and e[5].startswith("belief_nlp ") for e in exps)
    runs = conn.execute("SELECT r.id, e.alpha, r.seed, p.name, r.best_cost, r.solved, r.status, r.time, "
                        "r.planner_cost FROM runs r JOIN experiments e ON r.experimentid = e.id "
                        "JOIN plannerConfigs p ON r.plannerid = p.id").fetchall()
    assert len(runs) == len(rows) == 8
    assert sum(r[5] for r in runs) >= 6, "most runs must have a path (else this test checks little)"
    enum = dict(conn.execute("SELECT value, description FROM enums WHERE name = 'status'").fetchall())
    by_key = {(r["alpha"], r["seed"], f"igrrt/{r['method']}"): r for r in rows}
    for run_id, alpha, seed, config, best, solved, status, t, planner_cost in runs:
        rec = by_key[(alpha, seed, config)]
        assert enum[status] == rec["status"]
        assert bool(solved) == (rec["safe"] and rec["status"] not in ("plan_failed", "warm_start_failed", "error"))
        if rec["safe"]:
            assert best == pytest.approx(rec["cost"], rel=1e-12) and t == pytest.approx(rec["wall_time"])
        # progress: the planner's curve ends at its cost; the smoother's curve starts at the warm
        # start after planning and ends at the run's cost
        prog = conn.execute("SELECT time, best_cost, planner_best_cost FROM progress WHERE runid = ? ORDER BY time",
                            (run_id,)).fetchall()
        plan_pts = [p for p in prog if p[2] is not None]
        cost_pts = [p for p in prog if p[1] is not None]
        if rec["status"] == "plan_failed":
            assert not cost_pts
            continue
        assert plan_pts[-1][2] == pytest.approx(planner_cost) == pytest.approx(rec["planner_cost"])
        assert cost_pts[0][0] == pytest.approx(rec["plan_time"] + rec["warm_start_time"])
        assert cost_pts[0][1] == pytest.approx(rec["warm_start_cost"])
        assert cost_pts[-1][1] == pytest.approx(rec["cost"]) and cost_pts[-1][0] <= rec["wall_time"] + 1e-9
        assert all(a[1] >= b[1] for a, b in zip(cost_pts, cost_pts[1:]))


@pytest.mark.skipif(importlib.util.find_spec("plannerarena") is None,
                    reason="Planner Arena (pip install plannerarena, in the test extra) is not installed")
def test_planner_arena_opens_and_plots_the_database(db, tmp_path):
    """The loader Planner Arena runs on an uploaded database, then its plots, drawn."""
    import plotnine as p9
    import polars as pl
    from plannerarena import performance
    from plannerarena.database import load_database

    data = load_database(db)
    assert data["problem_names"] == ["paper-multi"]
    assert data["parameters"] == ["alpha", "K"]
    assert {"time", "solved", "status", "best cost", "planner cost"} <= set(data["attributes"])
    runs = data["runs"]
    assert sorted(runs["planner"].cast(pl.String).unique().to_list()) == ["igrrt/ccp", "igrrt/none"]
    assert runs.height == 8 and set(runs["experiment"].to_list()) == {"paper-multi"}
    one = runs.filter(pl.col("alpha") == 0.1)
    figures = [performance.boxplot(one, "best cost", [], "o", False),
               performance.enums_plot(one, data["enums"], []),
               performance.ecdf_plot(one, "time", [])]
    progress = data["progress"].join(one.select(["id", "planner"]), left_on="runid", right_on="id")
    assert {"best cost", "planner best cost"} <= set(progress.columns) and progress.height > 0
    figures.append(p9.ggplot(progress, p9.aes(x="time", y="best cost", color="planner")) + p9.geom_point(na_rm=True))
    for i, fig in enumerate(figures):
        fig.save(tmp_path / f"arena_{i}.png", verbose=False)
        assert (tmp_path / f"arena_{i}.png").stat().st_size > 1000


@pytest.mark.skipif(importlib.util.find_spec("ompl") is None,
                    reason="OMPL's benchmark tools come with the 'ompl' extra, not installed here")
def test_ompl_compute_views_reads_the_database(db):
    from ompl.tools import computeViews

    computeViews(str(db), False)
    conn = sqlite3.connect(db)
    best = conn.execute("SELECT plannerid, avg_solved, avg_total_time FROM bestPlannerConfigs").fetchall()
    per_exp = conn.execute("SELECT * FROM bestPlannerConfigsPerExperiment").fetchall()
    assert len(best) == 2 and len(per_exp) == 4
    for pid, solved, t in best:
        mean_t = conn.execute("SELECT AVG(time) FROM runs WHERE plannerid = ?", (pid,)).fetchone()[0]
        assert 0 <= solved <= 1 and t == pytest.approx(mean_t)


def test_cli_export_and_errors(study_dir, tmp_path, capsys):
    out = tmp_path / "cli.db"
    assert main(["study", "export", str(study_dir), "--format", "ompl", "--out", str(out)]) == 0
    assert sqlite3.connect(out).execute("SELECT COUNT(*) FROM runs").fetchone()[0] == 8
    assert main(["study", "export", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert main(["study", "export", str(study_dir), "--format", "csv", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "records.jsonl" in err and "Traceback" not in err


def test_records_as_dataframe_or_rows_and_bad_input(study_dir, tmp_path):
    df = bn.load_records(study_dir)
    a = bn.export_ompl_benchmark(df, tmp_path / "a.db")
    b = bn.export_ompl_benchmark(list(bn.study.records.iter_records(study_dir)), tmp_path / "b.db")
    q = "SELECT seed, best_cost FROM runs ORDER BY seed, plannerid, best_cost"
    ra, rb = (sqlite3.connect(p).execute(q).fetchall() for p in (a, b))
    assert len(ra) == 8 and all(x[0] == y[0] and (x[1] == y[1] or math.isclose(x[1], y[1])) for x, y in zip(ra, rb))
    for bad, field in (([], "records"), (42, "records"), ([1, 2], "records[0]")):
        with pytest.raises(bn.ValidationError) as err:
            bn.export_ompl_benchmark(bad, tmp_path / "c.db")
        assert err.value.field == field
    with pytest.raises(bn.ValidationError) as err:
        bn.export_ompl_benchmark(df, 3)
    assert err.value.field == "path"
    assert json.loads(df["plan_trace"].iloc[0])      # the planner's anytime curve is recorded
