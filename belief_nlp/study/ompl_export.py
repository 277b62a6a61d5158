"""Study records as an OMPL benchmark database (Planner Arena, OMPL's statistics tools).

:func:`export_ompl_benchmark` writes the SQLite schema that OMPL's
``ompl_benchmark_statistics`` produces from benchmark logs and that Planner
Arena (``pip install plannerarena``) and ``ompl.tools.computeViews`` read,
so the database opens there without conversion:

``experiments``   one row per (scenario, alpha, K): ``name`` is the scenario;
                  the twelve standard columns (id, name, totaltime, timelimit,
                  memorylimit, runcount, version, hostname, cpuinfo, date,
                  seed, setup) come first, then the *problem parameters*
                  ``alpha`` and ``K`` (Planner Arena offers a filter for each
                  column after the twelfth).
``plannerConfigs`` one row per planner + smoothing method (+ the planner
                  settings when several share a name): ``"igrrt/auto"``,
                  ``"ompl:RRTstar/auto"``, ``"igrrt/none"`` (the raw plan);
                  ``settings`` holds the planner options and method options.
``enums``         the ``status`` enum (every status a record can carry).
``runs``          one row per record: ``id, experimentid, plannerid`` first
                  (Planner Arena takes every later column as an attribute),
                  then ``time`` (the path's total: planning + warm start +
                  smoothing, s), ``solved`` (a verified path was returned),
                  ``status`` (ENUM), ``best_cost`` (the smoother's K-step
                  objective of the returned path; the warm start's for
                  "none"), ``planner_cost``, ``warm_start_cost``, ``control``,
                  ``information``, ``iterations``, ``seed``, ``plan_time``,
                  ``warm_start_time``, ``smoothing_time``, ``correct_solution``
                  (passed the independent verifier), ``approximate_solution``
                  (always false), ``success`` (the method converged),
                  ``min_margin``, ``K_used`` and ``mc_rate`` (Monte-Carlo
                  failure rate, when simulated).
``progress``      the anytime curves, ``(runid, time)`` unique: ``time`` in
                  seconds from the start of planning; ``planner_best_cost``
                  is the planner's own objective during planning (IG-RRT*:
                  length + alpha * information; OMPL: path length);
                  ``best_cost`` is the smoother's objective from the warm
                  start on, one point per improving accepted iteration.

Columns named with underscores appear in Planner Arena with spaces
("best cost"), as OMPL's own.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable

from ..errors import ScenarioFileError, ValidationError

__all__ = ["export_ompl_benchmark", "RUN_COLUMNS", "PROGRESS_COLUMNS"]

#: (column, SQL type, record field or None when derived) of the runs table, after id, experimentid, plannerid.
RUN_COLUMNS = (
    ("time", "REAL", "wall_time"), ("solved", "BOOLEAN", None), ("status", "ENUM", None),
    ("best_cost", "REAL", "cost"), ("planner_cost", "REAL", "planner_cost"),
    ("warm_start_cost", "REAL", "warm_start_cost"), ("control", "REAL", "control"),
    ("information", "REAL", "information"), ("iterations", "INTEGER", "iterations"), ("seed", "INTEGER", "seed"),
    ("plan_time", "REAL", "plan_time"), ("warm_start_time", "REAL", "warm_start_time"),
    ("smoothing_time", "REAL", "smooth_time"), ("correct_solution", "BOOLEAN", "safe"),
    ("approximate_solution", "BOOLEAN", None), ("success", "BOOLEAN", "success"),
    ("min_margin", "REAL", "min_margin"), ("K_used", "INTEGER", "K_used"), ("mc_rate", "REAL", "mc_rate"),
)
#: Progress properties besides runid and time.
PROGRESS_COLUMNS = (("best_cost", "REAL"), ("planner_best_cost", "REAL"))

_STANDARD_EXPERIMENT = ("id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512), totaltime REAL, timelimit REAL, "
                        "memorylimit REAL, runcount INTEGER, version VARCHAR(128), hostname VARCHAR(1024), "
                        "cpuinfo TEXT, date DATETIME, seed VARCHAR(24), setup TEXT")


def _statuses() -> list[str]:
    """Every status a record can carry, in a fixed order (the enum's values)."""
    from ..smoother import STATUSES
    from .runner import FAILED, NO_SMOOTHING

    return list(dict.fromkeys([*STATUSES, "warm_start", *FAILED, NO_SMOOTHING]))


def _rows(records: Any) -> list[dict]:
    """Records as a list of dicts: a study folder / records.jsonl, a DataFrame or an iterable of dicts."""
    if isinstance(records, (str, os.PathLike)):
        from .records import iter_records

        p = Path(records)
        if not p.exists():
            raise ValidationError("records", f"{p} does not exist (give a study folder or its records.jsonl)")
        return list(iter_records(p))
    if hasattr(records, "to_dict") and hasattr(records, "columns"):
        return records.to_dict("records")
    if not isinstance(records, Iterable):
        raise ValidationError("records", f"must be a study folder, a DataFrame or rows (dicts), "
                                         f"got {type(records).__name__}")
    rows = list(records)
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise ValidationError(f"records[{i}]", f"must be a dict (a study row), got {type(r).__name__}")
    return rows


def _num(v: Any) -> float | None:
    """A finite float, or None (SQL NULL) for missing, NaN and infinite values."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _int(v: Any) -> int | None:
    f = _num(v)
    return None if f is None else int(f)


def _json(v: Any, default: Any) -> Any:
    if isinstance(v, str):
        try:
            return json.loads(v)
        except json.JSONDecodeError:
            return default
    return default if v is None else v


def _config_names(rows: list[dict]) -> list[tuple[str, str]]:
    """(name, settings) of each row's planner configuration; names unique per distinct settings."""
    base, settings = [], []
    for r in rows:
        planner = _json(r.get("planner"), {})
        name = f"{r.get('planner_name') or planner.get('planner', 'igrrt')}/{r.get('method', '?')}"
        opts = {k: v for k, v in sorted(planner.items()) if k != "planner"}
        base.append((name, opts))
        settings.append(f"planner: {json.dumps(planner, sort_keys=True)};method: {r.get('method_name', '')};"
                        f"method_options: {r.get('method_options', '{}')};")
    by_name: dict[str, set] = {}
    for name, opts in base:
        by_name.setdefault(name, set()).add(json.dumps(opts, sort_keys=True))
    out = []
    for (name, opts), st in zip(base, settings):
        if len(by_name[name]) > 1:      # several planner settings under one name: tell them apart
            name += " {" + ", ".join(f"{k}={v}" for k, v in opts.items()) + "}"
        out.append((name, st))
    return out


def _progress(r: dict) -> dict[float, dict[str, float]]:
    """time -> {column: value} for one row (planner curve, then the smoother's from the warm start)."""
    points: dict[float, dict[str, float]] = {}
    for t, c in _json(r.get("plan_trace"), []) or []:
        if _num(t) is not None and _num(c) is not None:
            points.setdefault(float(t), {})["planner_best_cost"] = float(c)
    t0 = (_num(r.get("plan_time")) or 0.0) + (_num(r.get("warm_start_time")) or 0.0)
    ws = _num(r.get("warm_start_cost"))
    best = math.inf
    if ws is not None and r.get("status") not in ("plan_failed", "warm_start_failed"):
        points.setdefault(t0, {})["best_cost"] = best = ws
    # the best so far: the answer is never above the warm start, so iterates above it are not progress
    for t, c in _json(r.get("trace"), []) or []:
        if _num(t) is not None and _num(c) is not None and float(c) < best:
            points.setdefault(float(t), {})["best_cost"] = best = float(c)
    return points


def export_ompl_benchmark(records: Any, path: str | os.PathLike) -> Path:
    """Write study records as an OMPL benchmark database (SQLite) at ``path``.

    Parameters
    ----------
    records : str, path, DataFrame or iterable of dict
        A study folder (or its ``records.jsonl``), the DataFrame of
        :func:`belief_nlp.load_records`, or an iterable of record dicts.
    path : str or path
        The database file; an existing file is replaced.

    Returns
    -------
    Path
        ``path``. Open it in Planner Arena (``pip install plannerarena``, then
        ``plannerarena`` and upload it) or with ``ompl.tools.computeViews``.
        The tables are described in :mod:`belief_nlp.study.ompl_export`.

    Raises
    ------
    ValidationError
        No records, or records of the wrong type (field ``records``).
    ScenarioFileError
        The file cannot be written (field ``path``).
    """
    from .._version import __version__

    rows = _rows(records)
    if not rows:
        raise ValidationError("records", "no study records to export")
    if not isinstance(path, (str, os.PathLike)):
        raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
    path = Path(path)
    statuses = _statuses()
    status_code = {s: i for i, s in enumerate(statuses)}
    configs = _config_names(rows)
    try:
        if path.exists():
            path.unlink()
        conn = sqlite3.connect(path)
    except (OSError, sqlite3.Error) as exc:
        raise ScenarioFileError("path", f"cannot write {str(path)[:200]}: {exc}") from exc
    try:
        c = conn.cursor()
        c.execute("PRAGMA FOREIGN_KEYS = ON")
        run_cols = ", ".join(f"{n} {t}" for n, t, _ in RUN_COLUMNS)
        prog_cols = ", ".join(f"{n} {t}" for n, t in PROGRESS_COLUMNS)
        c.executescript(f"""
            CREATE TABLE experiments ({_STANDARD_EXPERIMENT}, alpha REAL, K INTEGER);
            CREATE TABLE plannerConfigs (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512) NOT NULL,
                settings TEXT);
            CREATE TABLE enums (name VARCHAR(512), value INTEGER, description TEXT, PRIMARY KEY (name, value));
            CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, experimentid INTEGER, plannerid INTEGER,
                {run_cols},
                FOREIGN KEY (experimentid) REFERENCES experiments(id) ON DELETE CASCADE,
                FOREIGN KEY (plannerid) REFERENCES plannerConfigs(id) ON DELETE CASCADE);
            CREATE TABLE progress (runid INTEGER, time REAL, {prog_cols}, PRIMARY KEY (runid, time),
                FOREIGN KEY (runid) REFERENCES runs(id) ON DELETE CASCADE);""")
        c.executemany("INSERT INTO enums VALUES (?, ?, ?)", [("status", i, s) for i, s in enumerate(statuses)])

        # experiments: one per (scenario, alpha, K)
        groups: dict[tuple, list[int]] = {}
        for i, r in enumerate(rows):
            groups.setdefault((str(r.get("scenario", "")), _num(r.get("alpha")), _int(r.get("K"))), []).append(i)
        exp_id: dict[tuple, int] = {}
        for key, idx in groups.items():
            sel = [rows[i] for i in idx]
            case = _json(sel[0].get("case"), {})
            limits = case.get("limits", {}) if isinstance(case, dict) else {}
            per_config: dict[str, int] = {}
            for i in idx:
                per_config[configs[i][0]] = per_config.get(configs[i][0], 0) + 1
            finished = [f for f in (_num(r.get("finished_at")) for r in sel) if f is not None]
            date = (datetime.fromtimestamp(min(finished), timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
                    if finished else None)
            setup = json.dumps({"study": sel[0].get("study"), "scenario": key[0],
                                "scenario_ref": sel[0].get("scenario_ref"), "alpha": key[1], "K": key[2],
                                "limits": limits}, sort_keys=True, default=str)
            versions = sorted({str(r.get("belief_nlp_version") or __version__) for r in sel})
            c.execute("INSERT INTO experiments (name, totaltime, timelimit, memorylimit, runcount, version, "
                      "hostname, cpuinfo, date, seed, setup, alpha, K) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
                      (key[0], sum(_num(r.get("wall_time")) or 0.0 for r in sel),
                       _num(limits.get("time_limit")), 0.0, max(per_config.values()),
                       f"belief_nlp {versions[-1]}", "", None, date,
                       ",".join(str(s) for s in sorted({_int(r.get("seed")) for r in sel} - {None})),
                       setup, key[1], key[2]))
            exp_id[key] = c.lastrowid
        # planner configurations
        cfg_id: dict[tuple[str, str], int] = {}
        for cfg in configs:
            if cfg not in cfg_id:
                c.execute("INSERT INTO plannerConfigs (name, settings) VALUES (?, ?)", cfg)
                cfg_id[cfg] = c.lastrowid
        # runs and their progress
        names = ", ".join(n for n, _, _ in RUN_COLUMNS)
        marks = ", ".join("?" * (len(RUN_COLUMNS) + 2))
        from .runner import FAILED

        for key, idx in groups.items():
            for i in idx:
                r = rows[i]
                status = str(r.get("status", "error"))
                solved = status not in FAILED and bool(r.get("safe"))
                values = []
                for name, sql_type, field in RUN_COLUMNS:
                    if name == "solved":
                        values.append(int(solved))
                    elif name == "status":
                        values.append(status_code.get(status, status_code["error"]))
                    elif name == "approximate_solution":
                        values.append(0)
                    elif name == "mc_rate" and not _int(r.get("mc_runs")):
                        values.append(None)
                    elif sql_type == "BOOLEAN":
                        values.append(None if r.get(field) is None else int(bool(r.get(field))))
                    elif sql_type == "INTEGER":
                        values.append(_int(r.get(field)))
                    else:
                        values.append(_num(r.get(field)))
                c.execute(f"INSERT INTO runs (experimentid, plannerid, {names}) VALUES ({marks})",
                          [exp_id[key], cfg_id[configs[i]], *values])
                run_id = c.lastrowid
                c.executemany("INSERT INTO progress (runid, time, best_cost, planner_best_cost) VALUES (?,?,?,?)",
                              [(run_id, t, p.get("best_cost"), p.get("planner_best_cost"))
                               for t, p in sorted(_progress(r).items())])
        conn.commit()
    except sqlite3.Error as exc:
        conn.close()
        raise ScenarioFileError("path", f"cannot write {str(path)[:200]}: {exc}") from exc
    conn.close()
    return path
