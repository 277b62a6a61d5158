"""Throughput and latency of the exact clearance geometry (belief_nlp.geometry).

On the built-in paper-multi scenario, against its hazards (6 obstacles + 4
walls) and against the 6 obstacles alone, with random transitions of length
0.1 m in the unit square (P_prev with eigenvalues in [1e-6, 1e-3] m^2, the
scenario's W):

* exact transition clearances per second (``transition_clearances``, n x m),
* boolean decisions per second (``transitions_clear``),
* ellipse clearances per second (``ellipse_clearances``),
* small-batch latency of the same calls (20 and 200 transitions),

and, for reference, the generic (any-dimension) path on cube3d. Timings are
the best of several repetitions, in wall time and in process CPU time: the
machine may be shared, so the load average is recorded too. Writes
benchmarks/results/geometry.json and prints a table.

    python benchmarks/bench_geometry.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp import geometry as geo


def random_transitions(rng: np.random.Generator, n: int, d: int, W: np.ndarray, length: float = 0.1):
    x0 = rng.uniform(0.0, 1.0, size=(n, d))
    u = rng.normal(size=(n, d))
    x1 = x0 + length * u / np.linalg.norm(u, axis=1, keepdims=True)
    Q, _ = np.linalg.qr(rng.normal(size=(n, d, d)))
    ev = 10.0 ** rng.uniform(-6, -3, size=(n, d))
    P0 = np.einsum("nij,nj,nkj->nik", Q, ev, Q)
    return x0, P0, x1, W


def best_time(fn, reps: int) -> tuple[float, float, float]:
    """(best wall, median wall, best CPU) seconds over ``reps`` calls."""
    fn()                                     # warm caches (PolytopeSet, imports)
    wall, cpu = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), float(np.median(wall)), min(cpu)


def measure(ps: geo.PolytopeSet, data, chi2: float, reps: int) -> dict:
    x0, P0, x1, W = data
    pairs = x0.shape[0] * len(ps)
    out = {"transitions": int(x0.shape[0]), "polytopes": len(ps), "pairs": pairs}
    calls = {
        "exact": lambda: geo.transition_clearances(x0, P0, x1, W, ps, chi2),
        "bool": lambda: geo.transitions_clear(x0, P0, x1, W, ps, chi2),
        "ellipse": lambda: geo.ellipse_clearances(x0, P0, ps, chi2),
    }
    for name, fn in calls.items():
        wall, med, cpu = best_time(fn, reps)
        out[name] = {"best_wall_s": wall, "median_wall_s": med, "best_cpu_s": cpu,
                     "pairs_per_s_wall": pairs / wall, "pairs_per_s_cpu": pairs / cpu if cpu > 0 else None}
    tm = geo.transition_minimiser(x0, P0, x1, W, ps)
    out["rounds"] = int(tm.iterations)
    out["fraction_clear"] = float(np.mean(tm.dist2 >= chi2))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller batches, fewer repetitions")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "geometry.json"))
    args = ap.parse_args()
    big, reps_big, reps_small = (1000, 3, 50) if args.quick else (5000, 7, 300)

    sc = bn.load_scenario("paper-multi")
    rng = np.random.default_rng(0)
    sets = {"hazards": geo.PolytopeSet.build(sc.hazards), "obstacles": geo.PolytopeSet.build(sc.obstacles)}
    rows = []
    for set_name, ps in sets.items():
        for n, reps in ((big, reps_big), (200, reps_small), (20, reps_small)):
            r = measure(ps, random_transitions(rng, n, 2, sc.W), sc.chi2, reps)
            rows.append({"scenario": "paper-multi", "set": set_name, "path": "planar", **r})
    cube = bn.load_scenario("cube3d")
    ps3 = geo.PolytopeSet.build(cube.hazards)
    for n, reps in ((big // 5, reps_big), (20, max(10, reps_small // 10))):
        r = measure(ps3, random_transitions(rng, n, 3, cube.W), cube.chi2, reps)
        rows.append({"scenario": "cube3d", "set": "hazards", "path": "generic", **r})

    record = {
        "benchmark": "geometry",
        "quick": args.quick,
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "python": platform.python_version(), "numpy": np.__version__,
                    "cpu_count": os.cpu_count(),
                    "load_average_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None},
        "notes": "pairs = transitions x polytopes; throughput from the best repetition; "
                 "'cpu' uses process CPU time (less sensitive to other load on a shared machine); "
                 "rounds = bracketing rounds of the vertex-curve iteration (planar) or of dist2(s) (generic).",
        "results": rows,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")

    print(f"{'scenario':12s}{'set':10s}{'n x m':>11s} {'exact pairs/s':>14s} {'(cpu)':>11s} {'bool pairs/s':>13s} "
          f"{'ellipse pairs/s':>16s} {'exact ms':>9s} {'bool ms':>8s} {'ellipse ms':>10s} {'rounds':>6s}")
    for r in rows:
        print(f"{r['scenario']:12s}{r['set']:10s}{r['transitions']:>6d} x {r['polytopes']:<2d} "
              f"{r['exact']['pairs_per_s_wall']:14,.0f} {r['exact']['pairs_per_s_cpu'] or float('nan'):11,.0f} "
              f"{r['bool']['pairs_per_s_wall']:13,.0f} "
              f"{r['ellipse']['pairs_per_s_wall']:16,.0f} {1e3 * r['exact']['best_wall_s']:9.3f} "
              f"{1e3 * r['bool']['best_wall_s']:8.3f} {1e3 * r['ellipse']['best_wall_s']:10.3f} {r['rounds']:6d}")
    la = record["machine"]["load_average_1_5_15"]
    print(f"(best of repetitions, wall time; load average {la}; written to {out})")


if __name__ == "__main__":
    main()
