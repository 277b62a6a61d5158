"""``belief-nlp study``: run a declarative solver-comparison study, report on it, export it, list built-ins."""

from __future__ import annotations

from pathlib import Path

from ..errors import ValidationError
from .common import EXIT_OK, _Run
from .parser import _nonneg_int, _output_args, _positive_int


def add_parser(sub) -> None:
    """Add the ``study`` subcommand (``run``, ``report``, ``export``, ``list``) to the subparsers ``sub``."""
    sp = sub.add_parser(
        "study", help="run a solver comparison study (TOML) on a process pool or a Dask cluster; report it",
        description="Solver comparison studies at scale (docs/studies.md). 'run' expands a study file into "
                    "cases (scenarios x seeds x alpha x K x planner settings), runs each case (plan, one warm "
                    "start, every method, verify) on a process pool or a Dask cluster and appends one row per "
                    "(case, method) to DIR/records.jsonl as cases finish; running it again on the same DIR "
                    "resumes. 'report' writes DIR/report.md and its figures. 'export' writes the records as an OMPL "
                    "benchmark database (Planner Arena). 'list' shows the built-in studies.",
        epilog="Examples:\n  belief-nlp study run study.toml --out results\n"
               "  belief-nlp study run smoke --out smoke --workers 2\n"
               "  belief-nlp study run study.toml --out results --dask tcp://scheduler:8786\n"
               "  belief-nlp study report results\n"
               "  belief-nlp study export results --format ompl --out results.db")
    actions = sp.add_subparsers(dest="action", required=True, metavar="ACTION", parser_class=type(sp))
    run = actions.add_parser("run", help="run (or resume) a study",
                             description="Run a study file (or a built-in study name) and stream its records "
                                         "to DIR/records.jsonl; rerunning on DIR skips finished cases.")
    run.add_argument("config", help="study TOML file, or a built-in study name (belief-nlp study list)")
    run.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder of the records (created)")
    run.add_argument("--workers", type=_positive_int, default=None,
                     help="local process-pool size (default: the number of cores)")
    run.add_argument("--dask", default=None, metavar="ADDRESS",
                     help="run on the Dask cluster at this scheduler address (tcp://host:8786)")
    run.add_argument("--retry-failed", action="store_true", help="rerun cases whose rows all failed")
    run.add_argument("--limit", type=_nonneg_int, default=None, help="run at most this many pending cases")
    run.add_argument("--report", action="store_true", help="write DIR/report.md when done")
    _output_args(run, out_default=None)
    run.set_defaults(func=_cmd_run)
    rep = actions.add_parser("report", help="write DIR/report.md and its figures from the records",
                             description="Per-method table (success, shifted geometric mean of time, cost "
                                         "ratio to the best), performance profiles, anytime curves, "
                                         "Monte-Carlo rates and failures, from DIR/records.jsonl.")
    rep.add_argument("directory", type=Path, metavar="DIR", help="the --out folder of 'study run'")
    _output_args(rep, out_default=None)
    rep.set_defaults(func=_cmd_report)
    ex = actions.add_parser("export", help="write the records in another tool's format (OMPL benchmark database)",
                            description="Write DIR's records as an OMPL benchmark database (SQLite: experiments, "
                                        "plannerConfigs, enums, runs, progress) that Planner Arena "
                                        "(pip install plannerarena) and OMPL's benchmark tools open as they are.",
                            epilog="Example:\n  belief-nlp study export results --format ompl --out results.db")
    ex.add_argument("directory", type=Path, metavar="DIR", help="the --out folder of 'study run'")
    ex.add_argument("--format", choices=("ompl",), default="ompl", help="ompl: OMPL's benchmark database (SQLite)")
    ex.add_argument("--out", type=Path, required=True, metavar="FILE", help="the database file (replaced)")
    _output_args(ex, out_default=None)
    ex.set_defaults(func=_cmd_export)
    ls = actions.add_parser("list", help="list the built-in studies", description="List the built-in studies.")
    _output_args(ls, out_default=None)
    ls.set_defaults(func=_cmd_list)


def _cmd_run(run: _Run) -> int:
    from ..study import load_study, run_study, write_report

    a = run.args
    study = load_study(a.config)
    summary = run_study(study, a.out, workers=a.workers, dask=a.dask, progress=not run.quiet,
                        retry_failed=a.retry_failed, limit=a.limit)
    if not run.quiet:
        print(f"study {study.name}: {summary.cases} cases, {summary.skipped} already recorded, {summary.ran} run "
              f"({summary.rows} rows, {summary.failed_rows} failed) in {summary.seconds:.1f} s on "
              f"{summary.executor}; records in {Path(a.out) / 'records.jsonl'}")
    if a.report:
        path = write_report(a.out)
        if not run.quiet:
            print(f"report: {path}")
    return EXIT_OK


def _cmd_report(run: _Run) -> int:
    from ..study import write_report

    d = run.args.directory
    if not (d / "records.jsonl").exists():
        raise ValidationError("DIR", f"{d} holds no records.jsonl (the --out folder of 'belief-nlp study run')")
    path = write_report(d)
    if not run.quiet:
        print(f"report: {path}")
    return EXIT_OK


def _cmd_export(run: _Run) -> int:
    from ..study import export_ompl_benchmark

    a = run.args
    if not (a.directory / "records.jsonl").exists():
        raise ValidationError("DIR", f"{a.directory} holds no records.jsonl (the --out folder of 'belief-nlp study run')")
    path = export_ompl_benchmark(a.directory, a.out)
    if not run.quiet:
        print(f"OMPL benchmark database: {path}")
    return EXIT_OK


def _cmd_list(run: _Run) -> int:
    from ..study import builtin_studies, load_study

    for name in builtin_studies():
        st = load_study(name)
        print(f"{name:10s} {st.description or st.name}: {st.n_cases()} cases")
    return EXIT_OK
