"""Construction cost of a process's calls: first call, repeated call, a new alpha.

Issue 21, item 5. Each code version runs in fresh processes, alternating with
an older copy of the package (``--baseline DIR``: a folder holding a
``belief_nlp`` package, e.g. ``git archive 5ceff4a belief_nlp | tar -x -C
/tmp/base``). One process: import, two per-step N = 500 plans of paper-multi,
then ``smooth(method="auto")`` at K: seed 0 alpha 0.1 (first), the same again,
seed 0 alpha 1.0 (a new alpha), and that again. Wall and CPU seconds per call
(CPU is the portable figure on a shared machine), the costs (which must not
change), the load average. Records go to benchmarks/results/construction.json
under ``--label``:

    python benchmarks/bench_construction.py --baseline /tmp/base --rounds 3 --label vs5ceff4a

``--disk-cache`` also runs the current code with the disk cache on
(``BELIEF_NLP_CACHE_DIR``): "disk-cold" in an empty folder per process (the
first process, which writes the entries), "disk-warm" in a folder one
untimed process filled before (every later process):

    python benchmarks/bench_construction.py --disk-cache --rounds 3 --label disk-cache

``--compiled`` also runs "disk-compiled": a warm folder whose derivative
functions were compiled (``BELIEF_NLP_CACHE_COMPILE=1``; the untimed process
that fills it starts the background build, which is waited for before any
timing):

    python benchmarks/bench_construction.py --disk-cache --compiled --rounds 3 --label compiled
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
CALLS = (("first", 0.1), ("again", 0.1), ("new_alpha", 1.0), ("again_alpha", 1.0))


def worker(package: str | None, K: int) -> dict:
    """The calls of one fresh process (module doc)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if package:
        sys.path.insert(0, package)
    t0 = time.perf_counter()
    import belief_nlp as bn

    out = {"import_s": time.perf_counter() - t0, "package": bn.__file__, "loadavg": os.getloadavg()[0]}
    sc = bn.load_scenario("paper-multi")
    path = bn.plan(sc, n_nodes=500, seed=0).path
    for name, alpha in CALLS:
        t, c = time.perf_counter(), time.process_time()
        r = bn.smooth(sc, path, K=K, alpha=alpha)
        out[name] = {"wall": time.perf_counter() - t, "cpu": time.process_time() - c, "cost": r.cost,
                     "method": r.method, "build": (r.stats.get("ipopt") or {}).get("build"), "verified": bool(bn.verify(sc, r.path).safe)}
    return out


def _summary(runs: list[dict]) -> dict:
    def med(f):
        return float(np.median([f(r) for r in runs]))

    out = {name: {k: med(lambda r, n=name, k=k: r[n][k]) for k in ("wall", "cpu")} for name, _ in CALLS}
    for kind in ("wall", "cpu"):
        out[f"first_minus_again_{kind}"] = med(lambda r, k=kind: r["first"][k] - r["again"][k])
        out[f"new_alpha_minus_again_{kind}"] = med(lambda r, k=kind: r["new_alpha"][k] - r["again_alpha"][k])
    out["loadavg"] = med(lambda r: r["loadavg"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="folder holding an older belief_nlp package")
    ap.add_argument("--rounds", type=int, default=3, help="fresh processes per version")
    ap.add_argument("--K", type=int, default=20)
    ap.add_argument("--label", default="current", help="key of this run in the JSON file")
    ap.add_argument("--out", type=Path, default=RESULTS / "construction.json")
    ap.add_argument("--disk-cache", action="store_true", help="also the current code with a cold and a warm disk cache")
    ap.add_argument("--compiled", action="store_true", help="also a warm folder with compiled derivative functions")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        print(json.dumps(worker(args.worker or None, args.K)))
        return
    versions = {"current": ""}
    if args.baseline:
        versions = {"baseline": str(args.baseline.resolve()), **versions}
    env = {k: v for k, v in os.environ.items() if k not in ("BELIEF_NLP_CACHE_DIR", "BELIEF_NLP_CACHE_COMPILE")}
    envs = {v: env for v in versions}
    tmp = tempfile.TemporaryDirectory(prefix="bench_construction_")
    if args.disk_cache:
        warm = os.path.join(tmp.name, "warm")
        envs["disk-warm"] = {**env, "BELIEF_NLP_CACHE_DIR": warm}
        versions.update({"disk-cold": "", "disk-warm": ""})
        subprocess.run([sys.executable, __file__, "--worker", "", "--K", str(args.K)], capture_output=True,
                       text=True, check=True, env=envs["disk-warm"])         # fills the warm folder
    if args.compiled:
        folder = Path(tmp.name) / "compiled"
        envs["disk-compiled"] = {**env, "BELIEF_NLP_CACHE_DIR": str(folder), "BELIEF_NLP_CACHE_COMPILE": "1"}
        versions["disk-compiled"] = ""
        subprocess.run([sys.executable, __file__, "--worker", "", "--K", str(args.K)], capture_output=True,
                       text=True, check=True, env=envs["disk-compiled"])
        t0 = time.monotonic()
        while not list(folder.glob("*.cso.pkl")) or list(folder.glob(".*.compiling")):   # the background build
            if time.monotonic() - t0 > 1800:
                raise SystemExit("the background compilation did not finish in 30 min")
            time.sleep(1)
        print(f"compiled in the background: {time.monotonic() - t0:.0f} s after the filling process", flush=True)
    runs: dict = {v: [] for v in versions}
    for r in range(args.rounds):
        if args.disk_cache:
            envs["disk-cold"] = {**env, "BELIEF_NLP_CACHE_DIR": os.path.join(tmp.name, f"cold{r}")}
        for v, package in versions.items():
            out = subprocess.run([sys.executable, __file__, "--worker", package, "--K", str(args.K)],
                                 capture_output=True, text=True, check=True, env=envs[v])
            runs[v].append(json.loads(out.stdout.strip().splitlines()[-1]))
            print(v, {k: round(runs[v][-1][k]["cpu"], 3) for k, _ in CALLS}, flush=True)
    record = {"settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}, "runs": runs,
              "summary": {v: _summary(r) for v, r in runs.items()},
              "finished": time.strftime("%Y-%m-%d %H:%M:%S")}
    if args.baseline:
        record["costs_equal"] = all(a[n]["cost"] == b[n]["cost"] for a, b in zip(runs["baseline"], runs["current"])
                                    for n, _ in CALLS)
    data = json.loads(args.out.read_text()) if args.out.exists() else {}
    data[args.label] = record
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1))
    print(json.dumps(record["summary"], indent=1))


if __name__ == "__main__":
    main()
