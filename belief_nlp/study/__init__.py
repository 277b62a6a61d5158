"""Solver comparison studies at scale (issue 12).

A :class:`Study` (TOML or Python) expands into :class:`Case` objects; each
case plans, builds one warm start, smooths with every method variant from it,
verifies and records one row per (case, method). :func:`run_study` runs the
cases on a process pool or a Dask cluster and streams the rows to
``DIR/records.jsonl``; :func:`load_records` reads them as a DataFrame;
:func:`write_report` writes ``DIR/report.md`` with its figures;
:func:`simulate` is the Monte-Carlo safety metric. Files, one idea each:

========================  ===================================================
``spec.py``               the Study, its TOML form, expansion into cases
``cases.py``              Case, MethodVariant, scenario references, stable keys
``runner.py``             one case -> rows (what workers run); the columns
``records.py``            JSON-lines store, resume, ``load_records``
``executors.py``          ``run_study``: process pool or Dask, bounded memory
``analysis.py``           qpbenchmark-style table, performance profiles, anytime curves
``report.py``             ``DIR/report.md`` and its figures
``montecarlo.py``         simulated collision rates with Clopper--Pearson intervals
``ompl_export.py``        the records as an OMPL benchmark database (Planner Arena)
``builtin/*.toml``        shipped studies ("smoke", "thesis", "baseline")
========================  ===================================================

Reference: docs/studies.md.
"""

from __future__ import annotations

from .cases import Case, Limits, MethodVariant, ScenarioRef, case_from_dict
from .executors import StudyRun, run_study
from .montecarlo import MonteCarloResult, clopper_pearson, simulate
from .ompl_export import export_ompl_benchmark
from .records import load_records
from .runner import TIMING_COLUMNS, run_case
from .spec import Study, builtin_studies, load_study

__all__ = ["Case", "Limits", "MethodVariant", "MonteCarloResult", "ScenarioRef", "Study", "StudyRun", "TIMING_COLUMNS",
           "builtin_studies", "case_from_dict", "clopper_pearson", "export_ompl_benchmark", "load_records",
           "load_study",
           "reproduce", "run_case", "run_study", "simulate", "write_report"]


def write_report(directory, **kwargs):
    """Write ``DIR/report.md`` and its figures (see :mod:`belief_nlp.study.report`)."""
    from .report import write_report as _write

    return _write(directory, **kwargs)


def reproduce(row) -> list[dict]:
    """Run again the case a record row came from (a dict or a DataFrame row); its fresh rows."""
    case = row["case"] if not isinstance(row, str) else row
    return run_case(case_from_dict(case))
