"""IG-RRT* on `quad`: cost and time against the authors' MATLAB runs.

The authors' IG-RRT* (MATLAB under Octave, edges checked at 10 intermediate
ellipses) on their default map `quad` (alpha = 0.1, W_rate = 1e-3 I per
metre, 90 % confidence, P0 = 1e-9 I) took 0.24 s per node:

    N = 500: 119 s, best cost 2.671;  N = 1000: 249 s, 2.068;  N = 2000: 557 s, 1.946

in their unit, metres + (alpha/2) (log2 det P_hat - log2 det P) per edge, i.e.
length + alpha * (entropy reduction in bits) = length + alpha * nats / ln 2.

This script runs our planner (exact continuous-time edge checks) for N = 500,
1000, 2000 and seeds 0..9, in these configurations:

* ``bits``: the authors' objective (``info_unit="bits"``), so the planner
  minimises exactly the cost they report; this is the comparison.
* ``nats``: our default objective, length + alpha * nats (alpha = 0.1 nats is a
  weight 1/ln 2 = 1.44 times lighter on information than theirs).
* ``bits-noBB`` (with ``--ablation``, the default of the full study): the
  authors' objective with branch-and-bound off, to show what pruning does.

Every run's best path is reported in both units: ours = length + 0.1 * nats,
theirs = length + 0.1 * nats / ln 2.

Writes benchmarks/results/planner_quad.json (machine, per-run records) and
benchmarks/results/planner_quad.png (median best cost against nodes), prints
a table. Time is CPU time of the planning process (``time.process_time``) and
wall time; the wall time includes whatever else the machine is running.

    python benchmarks/bench_planner.py            # full study (about five minutes)
    python benchmarks/bench_planner.py --quick    # 3 seeds, N = 500 and 1000
"""

from __future__ import annotations

import os

# One core: keep BLAS/OpenMP from spreading the small matrix work over threads.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import belief_nlp as bn  # noqa: E402
from belief_nlp.planner import plan  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
AUTHORS = {500: (119.0, 2.671), 1000: (249.0, 2.068), 2000: (557.0, 1.946)}   # N: (seconds, cost)
LN2 = math.log(2.0)


def machine_info() -> dict:
    info = {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "cpu_count": os.cpu_count(),
        "threads_env": {v: os.environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
    }
    try:
        info["cpu_model"] = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo")
                                 if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    try:
        info["load_average_start"] = os.getloadavg()
    except OSError:
        pass
    return info


CONFIGS = {"bits": {"info_unit": "bits"}, "nats": {"info_unit": "nats"},
           "bits-noBB": {"info_unit": "bits", "branch_and_bound": False}}


def run_one(sc, n: int, seed: int, objective: str) -> dict:
    res = plan(sc, n_nodes=n, seed=seed, **CONFIGS[objective])
    rec = {"objective": objective, "n_nodes": n, "seed": seed, "success": res.success,
           "cpu_s": res.timings["cpu"], "wall_s": res.timings["total"],
           "cpu_per_node_ms": 1e3 * res.timings["cpu"] / n, "wall_per_node_ms": 1e3 * res.timings["total"] / n,
           "first_solution_iteration": res.first_solution_iteration, "attempts": res.stats["attempts"],
           "edges_checked": res.stats["edges_checked"], "exact_edges": res.stats["collision_edges_exact"],
           "cost_history": [float(v) if math.isfinite(v) else None for v in res.cost_history]}
    if res.success:
        alpha = sc.alpha
        rec.update({"length_m": res.travel, "information_nats": res.information_nats,
                    "cost_ours": res.cost_in_nats(alpha), "cost_theirs": res.cost_in_authors_units(alpha),
                    "steps": res.path.K, "verified_min_margin": res.verification["min_margin"]})
    return rec


def _finite(obj):
    """The JSON tree with NaN/inf replaced by None (strict JSON has neither)."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def median(vals):
    vals = [v for v in vals if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def summarise(records: list[dict]) -> list[dict]:
    rows = []
    for obj in [c for c in CONFIGS if any(r["objective"] == c for r in records)]:
        for n in sorted({r["n_nodes"] for r in records}):
            rs = [r for r in records if r["objective"] == obj and r["n_nodes"] == n]
            if not rs:
                continue
            ok = [r for r in rs if r["success"]]
            rows.append({
                "objective": obj, "n_nodes": n, "runs": len(rs), "solved": len(ok),
                "median_cost_ours": median([r["cost_ours"] for r in ok]) if len(ok) == len(rs) else float("nan"),
                "median_cost_theirs": median([r["cost_theirs"] for r in ok]) if len(ok) == len(rs) else float("nan"),
                "authors_cost": AUTHORS.get(n, (None, None))[1],
                "median_cpu_s": median([r["cpu_s"] for r in rs]),
                "max_cpu_s": max(r["cpu_s"] for r in rs),
                "median_wall_s": median([r["wall_s"] for r in rs]),
                "max_wall_s": max(r["wall_s"] for r in rs),
                "median_cpu_per_node_ms": median([r["cpu_per_node_ms"] for r in rs]),
                "authors_s_per_node": AUTHORS[n][0] / n if n in AUTHORS else None,
                "median_first_solution": median([r["first_solution_iteration"] for r in rs]),
            })
    return rows


def print_table(rows: list[dict]) -> None:
    head = (f"{'objective':10s} {'N':>5s} {'solved':>6s} {'cost ours':>9s} {'cost theirs':>11s} {'authors':>7s} "
            f"{'CPU s':>6s} {'max':>5s} {'wall s':>6s} {'max':>5s} {'ms/node':>7s} {'1st sol.':>8s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        a = r["authors_cost"]
        print(f"{r['objective']:10s} {r['n_nodes']:5d} {r['solved']:3d}/{r['runs']:<2d} {r['median_cost_ours']:9.3f} "
              f"{r['median_cost_theirs']:11.3f} {a if a is not None else float('nan'):7.3f} "
              f"{r['median_cpu_s']:6.2f} {r['max_cpu_s']:5.2f} {r['median_wall_s']:6.2f} {r['max_wall_s']:5.2f} "
              f"{r['median_cpu_per_node_ms']:7.2f} {r['median_first_solution']:8.0f}")
    print("costs are medians over seeds; 'cost theirs' = length + 0.1 nats / ln 2 (the authors' unit); "
          "authors: 0.24 s per node")


def plot(records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    n_max = max(r["n_nodes"] for r in records)
    styles = {"bits": ("C0", "authors' objective (bits)"),
              "nats": ("C1", "our objective (nats)"),
              "bits-noBB": ("C2", "authors' objective, no branch-and-bound")}
    for obj, (color, label) in styles.items():
        runs = [r for r in records if r["objective"] == obj and r["n_nodes"] == n_max]
        if not runs:
            continue
        H = np.array([[np.inf if v is None else v for v in r["cost_history"]] for r in runs])
        with np.errstate(invalid="ignore"):
            med = np.median(H, axis=0)
        k = np.arange(1, H.shape[1] + 1)
        for h in H:
            ax.plot(k, h, color=color, alpha=0.15, linewidth=0.7)
        ax.plot(k, med, color=color, linewidth=2.0, label=f"{label}: median of {len(runs)} seeds")
    ns = sorted(AUTHORS)
    ax.plot(ns, [AUTHORS[n][1] for n in ns], "ks--", label="authors' IG-RRT* (MATLAB), their unit")
    ax.set_xlabel("nodes")
    ax.set_ylabel("best cost (planner's own unit)")
    ax.set_title("IG-RRT* on quad (alpha = 0.1): our planner vs the authors'")
    ax.set_ylim(1.2, 3.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds, N = 500 and 1000")
    ap.add_argument("--seeds", type=int, default=None, help="number of seeds (default 10, quick 3)")
    ap.add_argument("--objectives", nargs="+", default=None, choices=list(CONFIGS),
                    help="configurations to run (default: bits nats, plus bits-noBB in the full study)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    seeds = range(args.seeds if args.seeds is not None else (3 if args.quick else 10))
    sizes = [500, 1000] if args.quick else [500, 1000, 2000]
    objectives = args.objectives or (["bits", "nats"] if args.quick else list(CONFIGS))
    sc = bn.load_scenario("quad")
    info = machine_info()
    records = []
    t0 = time.perf_counter()
    for obj in objectives:
        for n in sizes:
            for s in seeds:
                rec = run_one(sc, n, s, obj)
                records.append(rec)
                print(f"{obj} N={n} seed={s}: cost theirs {rec.get('cost_theirs', float('nan')):.3f}  "
                      f"cpu {rec['cpu_s']:.2f} s  wall {rec['wall_s']:.2f} s  first solution "
                      f"{rec['first_solution_iteration']}", flush=True)
    # Anytime sanity check: a run with N nodes is the prefix of the run with more nodes.
    prefix_ok = all(
        r["cost_history"] == q["cost_history"][: r["n_nodes"]]
        for r in records for q in records
        if q["objective"] == r["objective"] and q["seed"] == r["seed"] and q["n_nodes"] > r["n_nodes"])
    try:
        info["load_average_end"] = os.getloadavg()
    except OSError:
        pass
    rows = summarise(records)
    out = {"benchmark": "IG-RRT* on quad vs the authors' MATLAB", "scenario": "quad", "alpha": sc.alpha,
           "machine": info, "authors": {str(n): {"seconds": s, "cost_theirs": c} for n, (s, c) in AUTHORS.items()},
           "units": {"ours": "length + alpha * information_nats",
                     "theirs": "length + alpha * information_nats / ln 2 (= metres + alpha/2 * log2-det bits)"},
           "prefix_property_holds": prefix_ok, "total_seconds": time.perf_counter() - t0,
           "summary": rows, "runs": records}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "planner_quad.json").write_text(json.dumps(_finite(out), indent=1, allow_nan=False))
    plot(records, args.out / "planner_quad.png")
    print_table(rows)
    print(f"prefix property (N-node run = first N nodes of a longer run): {prefix_ok}")
    print(f"wrote {args.out / 'planner_quad.json'} and {args.out / 'planner_quad.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
