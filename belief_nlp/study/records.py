"""Records on disk: JSON lines appended as cases finish, read back as a DataFrame.

``DIR/records.jsonl`` holds one JSON object per (case, method variant); a
case's rows are written together, flushed and synced before the next case is
taken, so an interrupted study loses at most the cases in flight. A torn last
line (a crash mid-write) is ignored on reading. ``DIR/study.json`` keeps the
study that wrote the records.

Rerunning a study on the same DIR resumes: :meth:`RecordStore.finished`
returns the keys of the cases already recorded (only the keys are held in
memory, never the rows).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, Iterator

__all__ = ["RecordStore", "load_records", "iter_records", "RECORDS_FILE"]

RECORDS_FILE = "records.jsonl"


def _clean(value: Any) -> Any:
    """JSON-able value: numpy scalars to Python, NaN kept (JSON lines allow NaN)."""
    if hasattr(value, "item") and not isinstance(value, (list, dict, str)):
        try:
            return value.item()
        except (ValueError, AttributeError):
            pass
    return value


def iter_records(directory: str | os.PathLike) -> Iterator[dict]:
    """The rows of ``DIR/records.jsonl`` one by one (torn lines skipped)."""
    path = Path(directory)
    if path.is_dir():
        path = path / RECORDS_FILE
    if not path.exists():
        return
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            line = line.strip()
            if not line:
                continue
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                continue   # torn last line from an interrupted run


class RecordStore:
    """Append-only store of study rows under a directory."""

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.path = self.directory / RECORDS_FILE

    def finished(self, retry_failed: bool = False) -> set[str]:
        """Keys of recorded cases; with ``retry_failed``, cases whose rows all
        failed (error, timeout) count as not finished."""
        done: set[str] = set()
        failed_only: dict[str, bool] = {}
        for row in iter_records(self.path):
            key = row.get("case_key")
            if key is None:
                continue
            done.add(key)
            bad = row.get("status") in ("error", "timeout")
            failed_only[key] = failed_only.get(key, True) and bad
        if retry_failed:
            done -= {k for k, bad in failed_only.items() if bad}
        return done

    def append(self, rows: Iterable[dict]) -> int:
        """Write one case's rows (a single write, then flush and fsync)."""
        text = "".join(json.dumps({k: _clean(v) for k, v in row.items()}, allow_nan=True, default=str) + "\n"
                       for row in rows)
        if not text:
            return 0
        with open(self.path, "a", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        return text.count("\n")

    def write_study(self, study_dict: dict) -> None:
        """Keep the study next to its records (``study.json``)."""
        (self.directory / "study.json").write_text(json.dumps(study_dict, indent=1, default=str))


def load_records(directory: str | os.PathLike, latest: bool = True):
    """The records of a study directory as a pandas DataFrame.

    Parameters
    ----------
    directory : str or os.PathLike
        A study's output folder (holding ``records.jsonl``).
    latest : bool, optional
        When a case was rerun (``retry_failed``), keep only its last rows
        (default True).

    Returns
    -------
    pandas.DataFrame
        One row per case and method. Missing numbers are NaN; JSON-valued
        columns (``planner``, ``method_options``, ``stats``, ``trace``,
        ``versions``, ``case``) stay text.
    """
    import pandas as pd

    rows = list(iter_records(directory))
    if not rows:
        return pd.DataFrame(columns=["case_key", "scenario", "seed", "alpha", "K", "method", "status", "success",
                                     "cost", "safe", "wall_time"])
    df = pd.DataFrame(rows)
    if latest and "case_key" in df and "method" in df:
        df = df.drop_duplicates(subset=["case_key", "method"], keep="last").reset_index(drop=True)
    for col in ("cost", "warm_start_cost", "planner_cost", "wall_time", "mc_rate"):
        if col in df:
            df[col] = pd.to_numeric(df[col], errors="coerce").astype(float)
    return df

