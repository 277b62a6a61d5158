"""Run a study's cases on a local process pool or a Dask cluster, streaming records to disk.

:func:`run_study` is the driver. It expands the study lazily, skips cases
already recorded in the output directory, keeps a bounded number of cases in
flight (twice the workers), and appends each finished case's rows to
``DIR/records.jsonl`` before it takes the next: the driver never holds the
study's results, so its memory does not grow with the number of cases.

Executors are existing engines, not home-made ones:

* ``concurrent.futures.ProcessPoolExecutor`` (default; workers = cores),
  started with "spawn" so no solver threads are inherited through fork;
* a Dask distributed cluster: a ``dask.distributed.Client`` or a scheduler
  address ("tcp://host:8786"). Workers need ``belief_nlp`` installed; cases
  travel as plain dicts (file scenarios carry their content).

Both call the same :func:`~belief_nlp.study.runner.run_case`, so the records
are the same whichever executor ran them (up to the timing columns).
A worker that dies (a crash in native code) costs the cases in flight an
"error" row; the pool is restarted and the study goes on.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from .cases import Case
from .records import RecordStore
from .runner import run_case
from .spec import Study, load_study

__all__ = ["run_study", "StudyRun"]

log = logging.getLogger("belief_nlp.study")


@dataclass
class StudyRun:
    """What :func:`run_study` did: counts only (the rows are on disk)."""

    directory: Path
    cases: int          # cases in the study
    skipped: int        # already recorded (resumed)
    ran: int            # run now
    rows: int           # rows written now
    failed_rows: int    # of which status plan_failed / warm_start_failed / error / timeout
    seconds: float
    executor: str


def _crash_rows(case: Case, exc: BaseException) -> list[dict]:
    from .runner import _fail_rows

    return _fail_rows(case, list(case.methods), "error", f"worker failed: {type(exc).__name__}: {exc}"[:2000], {})


def _pending(study: Study, done: set[str], limit: int | None) -> Iterator[Case]:
    n = 0
    for case in study.cases():
        if case.key in done:
            continue
        if limit is not None and n >= limit:
            return
        n += 1
        yield case


def _run_pool(cases: Iterator[Case], workers: int, sink: Callable[[Case, list[dict]], None]) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
    in_flight: dict[Any, Case] = {}
    exhausted = False
    try:
        while True:
            while not exhausted and len(in_flight) < 2 * workers:
                case = next(cases, None)
                if case is None:
                    exhausted = True
                    break
                in_flight[pool.submit(run_case, case)] = case
            if not in_flight:
                break
            finished, _ = wait(in_flight, return_when=FIRST_COMPLETED)
            broken = False
            for fut in finished:
                case = in_flight.pop(fut)
                try:
                    rows = fut.result()
                except BrokenProcessPool as exc:
                    broken = True
                    rows = _crash_rows(case, exc)
                except Exception as exc:  # noqa: BLE001 - record and go on
                    rows = _crash_rows(case, exc)
                sink(case, rows)
            if broken:
                # every future of a broken pool fails: record them, start a new pool
                for fut, case in list(in_flight.items()):
                    sink(case, _crash_rows(case, RuntimeError("the process pool broke while this case ran")))
                in_flight.clear()
                pool.shutdown(wait=False, cancel_futures=True)
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_dask(cases: Iterator[Case], client: Any, sink: Callable[[Case, list[dict]], None]) -> None:
    from dask.distributed import as_completed

    workers = max(1, sum(int(n) for n in (client.nthreads() or {}).values()))
    window = 2 * workers
    ac = as_completed()
    by_key: dict[str, Case] = {}

    def submit(case: Case) -> None:
        fut = client.submit(run_case, case.to_dict(), key=f"belief-nlp-case-{case.key}-{time.time_ns()}",
                            pure=False)
        by_key[fut.key] = case
        ac.add(fut)

    for _ in range(window):
        case = next(cases, None)
        if case is None:
            break
        submit(case)
    for fut in ac:
        case = by_key.pop(fut.key)
        try:
            rows = fut.result()
        except Exception as exc:  # noqa: BLE001 - a worker lost, a task error: record and go on
            rows = _crash_rows(case, exc)
        fut.release()
        sink(case, rows)
        nxt = next(cases, None)
        if nxt is not None:
            submit(nxt)


class _Silent:
    """No progress at all (``progress=False``)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def run_study(study: Study | str | os.PathLike | dict, out: str | os.PathLike, *, workers: int | None = None,
              dask: Any = None, progress: bool = True, retry_failed: bool = False,
              limit: int | None = None) -> StudyRun:
    """Run ``study`` and stream its records to ``out/records.jsonl``.

    Parameters
    ----------
    study : a :class:`Study`, a TOML file, a built-in study name or the TOML tree.
    out : output directory; rerunning on it resumes (recorded cases are skipped).
    workers : process-pool size (default: the number of cores).
    dask : a ``dask.distributed.Client`` or a scheduler address; the cluster
        runs the cases instead of the local pool.
    progress : a tqdm bar over the cases to run (stderr).
    retry_failed : also rerun cases whose rows all failed (error / timeout).
    limit : run at most this many pending cases (then stop; rerun to go on).

    Returns
    -------
    StudyRun with the counts; the rows are in ``out`` (:func:`load_records`).
    """
    from .._progress import progress_bar

    study = load_study(study)
    store = RecordStore(out)
    store.write_study(study.to_dict())
    done = store.finished(retry_failed=retry_failed)
    total, skipped = 0, 0
    for case in study.cases():          # one pass for the counts (keys only)
        total += 1
        skipped += case.key in done
    todo = total - skipped if limit is None else min(limit, total - skipped)
    counts = {"ran": 0, "rows": 0, "failed": 0}
    # a bar on a terminal or in Jupyter, log lines every few seconds in a CI log or a file
    bar = progress_bar(todo, f"study {study.name}", unit="case") if progress else _Silent()

    def sink(case: Case, rows: list[dict]) -> None:
        store.append(rows)
        counts["ran"] += 1
        counts["rows"] += len(rows)
        counts["failed"] += sum(r.get("status") in ("plan_failed", "warm_start_failed", "error", "timeout")
                                for r in rows)
        bar.update(1)

    t0 = time.perf_counter()
    cases = _pending(study, done, limit)
    try:
        if dask is not None:
            from dask.distributed import Client

            client = Client(dask) if isinstance(dask, str) else dask
            try:
                _run_dask(cases, client, sink)
            finally:
                if isinstance(dask, str):
                    client.close()
            executor = "dask"
        else:
            n = int(workers) if workers else (os.cpu_count() or 1)
            _run_pool(cases, max(1, n), sink)
            executor = f"process-pool[{max(1, n)}]"
    finally:
        bar.close()
    return StudyRun(Path(out), total, skipped, counts["ran"], counts["rows"], counts["failed"],
                    time.perf_counter() - t0, executor)
