"""Shared by the benchmark scripts: run cases in a process pool and write one
JSON record (machine, load averages before and after, version, arguments,
summary table, per-case records); write a figure next to the records."""

from __future__ import annotations

import json
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable


def cpu_seconds() -> float:
    """CPU seconds of this process and of its waited-for children: method
    "fatrop" solves in forked children (belief_nlp.methods.nlp_guarded),
    which time.process_time() does not count."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def run_and_record(run_case: Callable[[dict], dict], cases: list[dict], summarise: Callable[[list], dict],
                   args, out: Path, workers: int) -> dict:
    """``run_case`` over ``cases`` in ``workers`` processes, ``summarise`` of the
    records; writes ``out`` and prints the table. Returns the document."""
    t0, load0 = time.time(), os.getloadavg()
    with ProcessPoolExecutor(workers) as ex:
        records = list(ex.map(run_case, cases))
    return write_record(out, args, summarise(records), records, t0, load0)


def write_record(out: Path, args, table: dict, records: list, t0: float, load0: tuple) -> dict:
    """Write one record to ``out`` (started at ``time.time()`` ``t0`` with load
    averages ``load0``) and print its table. Returns the document."""
    import belief_nlp as bn

    doc = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load_start": load0,
                       "load_end": os.getloadavg()}, "version": bn.__version__, "wall_total": time.time() - t0,
           "args": vars(args) | {"out": str(out)}, "table": table, "records": records}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1, default=str))
    print(json.dumps(table, indent=1))
    return doc


def wait_for_compiled(folder: Path, expected: int, limit_s: float = 3600.0) -> float:
    """Wait until the disk cache ``folder`` holds ``expected`` compiled
    derivative entries and no background build runs; returns the seconds
    waited (the benchmarks that time compiled derivatives start after it)."""
    t0 = time.monotonic()
    while list(folder.glob(".*.compiling")) or len(list(folder.glob("*.cso.pkl"))) < expected:
        if time.monotonic() - t0 > limit_s:
            raise SystemExit(f"the background compilation did not finish in {limit_s:.0f} s")
        time.sleep(2)
    waited = time.monotonic() - t0
    print(f"compiled {len(list(folder.glob('*.lib.so')))} libraries in {waited:.0f} s", flush=True)
    return waited


def write_figure(fig, out: Path, dpi: int = 110) -> None:
    """Save a matplotlib figure to ``out`` (its folder made), close it, say where."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    fig.clf()
    print(f"wrote {out}")
