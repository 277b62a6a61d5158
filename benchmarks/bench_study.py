"""Study executor benchmark (issue 12, performance section).

1. Speed-up: one study (paper-multi and M random maps, S seeds, 2 alphas,
   every registered method plus "none"; small planner and iteration limits)
   run with 1 and with 2 pool workers; the ratio of wall times.
2. Driver overhead per case: the driver process's own CPU time (expansion,
   submission, collecting, writing records -- planning and solving happen in
   the workers) divided by the cases.
3. Driver memory: tracemalloc peak of the driver over studies of growing size
   (cheap cases: method "none"); flat means the driver holds no results.
4. Monte Carlo: 10,000 runs of a K = 20 path (median of 5).

Writes benchmarks/results/study.json.

    python benchmarks/bench_study.py [--maps 20 --seeds 5]   # the issue's 210 cases (long)
    python benchmarks/bench_study.py --maps 4 --seeds 2      # 20 cases
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.study import Study, run_study, simulate

HERE = Path(__file__).resolve().parent / "results"


def _study(maps: int, seeds: int, methods: list[str], n_nodes: int = 100) -> Study:
    return Study(name="bench", scenarios=["paper-multi", f"random-polygons:{maps}"], seeds=list(range(seeds)),
                 alpha=[0.1, 1.0], K=[12], methods=methods, planner={"n_nodes": n_nodes},
                 solver={m: {"max_iter": 3 if m == "ccp" else 30} for m in methods if m != "none"})


def _timed_run(study: Study, workers: int) -> dict:
    d = tempfile.mkdtemp(prefix="bench_study_")
    try:
        cpu0, t0 = time.process_time(), time.perf_counter()
        run = run_study(study, d, workers=workers, progress=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        df = bn.load_records(d)
        return {"workers": workers, "cases": run.ran, "wall_s": wall, "driver_cpu_s": cpu,
                "driver_cpu_per_case_ms": 1e3 * cpu / max(1, run.ran),
                "work_s": float(df.drop_duplicates("case_key")["plan_time"].fillna(0).sum()
                                + df["smooth_time"].fillna(0).sum() + df.drop_duplicates("case_key")
                                ["warm_start_time"].fillna(0).sum())}
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _driver_memory(sizes: list[int]) -> list[dict]:
    out = []
    for seeds in sizes:
        st = Study(name="mem", scenarios=["random-polygons:5"], seeds=list(range(seeds)), alpha=[0.1], K=[0],
                   methods=["none"], planner={"n_nodes": 30})
        d = tempfile.mkdtemp(prefix="bench_mem_")
        tracemalloc.start()
        try:
            run = run_study(st, d, workers=2, progress=False)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
            shutil.rmtree(d, ignore_errors=True)
        out.append({"cases": run.ran, "driver_peak_MiB": peak / 2**20})
    return out


def _montecarlo() -> dict:
    sc = bn.load_scenario("paper-multi")
    planned = bn.plan(sc, n_nodes=300, seed=0, noise="per_step")
    path = bn.warm_start(sc, planned.path, K=20).path
    simulate(sc, path, runs=100)
    times = []
    for i in range(5):
        t = time.perf_counter()
        mc = simulate(sc, path, runs=10_000, substeps=20, seed=i)
        times.append(time.perf_counter() - t)
    return {"runs": 10_000, "K": 20, "substeps": 20, "median_s": float(np.median(times)), "rate": mc.rate,
            "summary": mc.summary()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--maps", type=int, default=20)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    methods = ["none"] + bn.available_methods()
    study = _study(args.maps, args.seeds, methods)
    load = os.getloadavg()
    one = _timed_run(study, 1)
    two = _timed_run(study, 2)
    res = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": load, "loadavg_at_end": os.getloadavg()},
           "study": {"cases": one["cases"], "methods": methods, "maps": args.maps, "seeds": args.seeds},
           "one_worker": one, "two_workers": two, "speedup": one["wall_s"] / two["wall_s"],
           "driver_memory": _driver_memory([4, 16, 48]), "montecarlo": _montecarlo()}
    HERE.mkdir(exist_ok=True)
    (HERE / "study.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
