"""IG-RRT* speed on paper-multi: wall and CPU time per node, and the best-cost distribution.

Issue 21, item 6: ``bn.plan(bn.load_scenario("paper-multi"), n_nodes=2000,
seed=s, noise="per_step")`` at most 0.75 s, at the same cost distribution.
(paper-multi's ``[planner] noise`` is per_step, so that is also the default
noise; ``--noise per_metre`` adds the authors' noise model.)

One record per run: N, seed, noise, wall and CPU time of the ``plan`` call,
per-node times, best cost, success, the load average (``os.getloadavg()``)
before and after the run, and a fingerprint of the tree (SHA-1 of the node
means, covariances and parents), so that two code versions can be compared
plan by plan: equal fingerprints mean identical trees. Timings use seeds
0..``--seeds``-1; the cost distribution uses N = 2000 over seeds
0..``--cost-seeds``-1 (the first ``--seeds`` of them are the timed runs).

Records go to ``benchmarks/results/planner_speed.json`` under ``--label``
(other labels in the file are kept), so the same script measures the code
before a change and after it:

    PYTHONPATH=/path/to/old/checkout python benchmarks/bench_planner_speed.py --label before
    PYTHONPATH=$PWD python benchmarks/bench_planner_speed.py --label after

With both labels present the file also gets a ``comparison``: median wall
and CPU ratios, cost quartiles, and how many seeds gave identical trees.

On a shared machine the load changes between two such runs, so the fair
comparison is paired: ``--baseline DIR`` (a checkout of the old code, the
folder that holds its ``belief_nlp`` package) imports the old package next to
the current one under another name and runs every case with the old code,
then the new, one after the other; the records go under ``before-paired``
and ``after-paired`` and the comparison ``paired_comparison`` adds the
per-run CPU ratios:

    git archive b6ff00d belief_nlp | tar -x -C /tmp/old
    PYTHONPATH=$PWD python benchmarks/bench_planner_speed.py --label paired --baseline /tmp/old

With another ``--label`` L the paired records are ``L-before-paired`` and
``L-after-paired`` and the comparison ``L-paired_comparison``, so that
several paired runs (against different old versions) stay in one file.

``--backends numpy numba`` runs every case with each planner backend
(``PlannerOptions.backend``), one after the other (paired, as above): records
``L-numpy`` and ``L-numba``, comparison ``L-backend_comparison``. With
``--compile-cost`` the script first measures, in fresh processes, the import
of numba and the first ``plan`` call of each backend with an empty numba
cache (compilation) and with the cache written (record ``L-compile``):

    PYTHONPATH=$PWD python benchmarks/bench_planner_speed.py --label round4 --sizes 2000 --seeds 5 \
        --backends numpy numba --compile-cost
"""

from __future__ import annotations

import os

# One core: keep BLAS/OpenMP from spreading the small matrix work over threads.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import belief_nlp as bn  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_planner import _finite, machine_info  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
OUT_NAME = "planner_speed.json"


def fingerprint(res) -> str:
    """SHA-1 of the tree's means, covariances and parents (identical trees <=> equal)."""
    h = hashlib.sha1()
    for arr in (res.tree.x, res.tree.P, res.tree.parent):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def baseline_module(folder: Path):
    """The package ``belief_nlp`` of ``folder``, imported as ``belief_nlp_baseline``
    (its imports are relative, so it runs next to the current one)."""
    alias = Path(tempfile.mkdtemp(prefix="bench_baseline_"))
    (alias / "belief_nlp_baseline").symlink_to(Path(folder).resolve() / "belief_nlp", target_is_directory=True)
    sys.path.insert(0, str(alias))
    return importlib.import_module("belief_nlp_baseline")


def run_one(sc, n: int, seed: int, noise: str, lib=bn, **kw) -> dict:
    load0 = os.getloadavg()
    c0, t0 = time.process_time(), time.perf_counter()
    res = lib.plan(sc, n_nodes=n, seed=seed, noise=noise, **kw)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"n_nodes": n, "seed": seed, "noise": noise, "success": bool(res.success), "best_cost": res.cost,
            "wall_s": wall, "cpu_s": cpu, "wall_per_node_ms": 1e3 * wall / n, "cpu_per_node_ms": 1e3 * cpu / n,
            "attempts": res.stats["attempts"], "edges_checked": res.stats["edges_checked"],
            "fingerprint": fingerprint(res), "load_before": load0, "load_after": os.getloadavg(),
            "backend": res.stats.get("backend", "numpy")}


_FIRST_CALL = """
import os, time
c0, t0 = time.process_time(), time.perf_counter()
import belief_nlp as bn
c1, t1 = time.process_time(), time.perf_counter()
if {numba!r}:
    import numba
c2, t2 = time.process_time(), time.perf_counter()
sc = bn.load_scenario("paper-multi")
res = bn.plan(sc, n_nodes=200, seed=0, backend={backend!r})
c3, t3 = time.process_time(), time.perf_counter()
print(c1 - c0, t1 - t0, c2 - c1, t2 - t1, c3 - c2, t3 - t2, res.timings["cpu"], os.getloadavg()[0])
"""


def compile_cost() -> dict:
    """Fresh processes: the import of belief_nlp and of numba, and the first
    ``plan`` call (N = 200) of each backend; for numba with an empty cache
    (a new ``NUMBA_CACHE_DIR``: compilation) and again with the cache it
    wrote. CPU and wall seconds."""
    keys = ("import_belief_nlp_cpu_s", "import_belief_nlp_wall_s", "import_numba_cpu_s", "import_numba_wall_s",
            "first_plan_cpu_s", "first_plan_wall_s", "plan_call_cpu_s", "load_1min")
    out = {}
    with tempfile.TemporaryDirectory(prefix="numba_cache_") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for name, backend in (("numpy", "numpy"), ("numba_empty_cache", "numba"), ("numba_cached", "numba"),
                              ("numba_cached_again", "numba")):
            code = _FIRST_CALL.format(numba=backend == "numba", backend=backend)
            line = subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True,
                                  text=True).stdout.split()
            out[name] = dict(zip(keys, map(float, line)))
            print("first call", name, json.dumps(out[name]), flush=True)
    return out


def _quartiles(vals) -> list[float]:
    return [float(q) for q in np.percentile(vals, [25, 50, 75])] if len(vals) else []


def summarise(runs: list[dict], timed_seeds: int) -> list[dict]:
    rows = []
    for noise in sorted({r["noise"] for r in runs}):
        for n in sorted({r["n_nodes"] for r in runs}):
            rs = [r for r in runs if r["noise"] == noise and r["n_nodes"] == n]
            if not rs:
                continue
            timed = [r for r in rs if r["seed"] < timed_seeds]
            costs = [r["best_cost"] for r in rs if r["success"]]
            rows.append({
                "noise": noise, "n_nodes": n, "timed_runs": len(timed), "cost_runs": len(rs),
                "solved": sum(r["success"] for r in rs),
                "median_wall_s": float(np.median([r["wall_s"] for r in timed])),
                "max_wall_s": max(r["wall_s"] for r in timed),
                "median_cpu_s": float(np.median([r["cpu_s"] for r in timed])),
                "median_wall_per_node_ms": float(np.median([r["wall_per_node_ms"] for r in timed])),
                "median_cpu_per_node_ms": float(np.median([r["cpu_per_node_ms"] for r in timed])),
                "cost_quartiles": _quartiles(costs),
                "mean_load_1min": float(np.mean([r["load_before"][0] for r in timed])),
            })
    return rows


def compare(before: dict, after: dict, paired: bool = False) -> list[dict]:
    """Per (noise, N): speed-up of the medians, cost quartiles, identical trees;
    ``paired``: also the quartiles of the per-run CPU and wall ratios."""
    out = []
    for rb in before["summary"]:
        ra = next((r for r in after["summary"] if r["noise"] == rb["noise"] and r["n_nodes"] == rb["n_nodes"]), None)
        if ra is None:
            continue
        key = (rb["noise"], rb["n_nodes"])
        fb = {r["seed"]: r for r in before["runs"] if (r["noise"], r["n_nodes"]) == key}
        fa = {r["seed"]: r for r in after["runs"] if (r["noise"], r["n_nodes"]) == key}
        common = sorted(set(fb) & set(fa))
        out.append({
            "noise": rb["noise"], "n_nodes": rb["n_nodes"],
            "wall_speedup": rb["median_wall_s"] / ra["median_wall_s"],
            "cpu_speedup": rb["median_cpu_s"] / ra["median_cpu_s"],
            "median_wall_s": [rb["median_wall_s"], ra["median_wall_s"]],
            "median_cpu_s": [rb["median_cpu_s"], ra["median_cpu_s"]],
            "cost_quartiles": [rb["cost_quartiles"], ra["cost_quartiles"]],
            "seeds_compared": len(common),
            "identical_trees": sum(fb[s]["fingerprint"] == fa[s]["fingerprint"] for s in common),
            "max_relative_cost_difference": max((abs(fb[s]["best_cost"] - fa[s]["best_cost"])
                                                 / abs(fb[s]["best_cost"]) for s in common
                                                 if fb[s]["success"] and fa[s]["success"]), default=None),
            "mean_load_1min": [rb["mean_load_1min"], ra["mean_load_1min"]],
        })
        if paired:
            out[-1]["cpu_ratio_quartiles"] = _quartiles([fb[s]["cpu_s"] / fa[s]["cpu_s"] for s in common])
            out[-1]["wall_ratio_quartiles"] = _quartiles([fb[s]["wall_s"] / fa[s]["wall_s"] for s in common])
            out[-1]["total_cpu_ratio"] = (sum(fb[s]["cpu_s"] for s in common) / sum(fa[s]["cpu_s"] for s in common))
    return out


def plot_backends(data: dict, label: str, out: Path) -> Path:
    """Two panels from the records ``label-numpy`` and ``label-numba``: CPU
    seconds per plan by seed and noise model, and the best-cost distributions
    (empirical CDFs over the cost seeds) of the largest N, per step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = {b: data["records"][f"{label}-{b}"]["runs"] for b in ("numpy", "numba")}
    n_max = max(r["n_nodes"] for r in recs["numpy"])
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.8))
    for b, colour in (("numpy", "tab:blue"), ("numba", "tab:orange")):
        for noise, marker in (("per_step", "o"), ("per_metre", "s")):
            timed = [r for r in recs[b] if r["n_nodes"] == n_max and r["noise"] == noise and r["seed"] < 5]
            if timed:
                ax0.plot([r["seed"] for r in timed], [r["cpu_s"] for r in timed], marker, color=colour,
                         label=f"{b}, {noise.replace('_', ' ')}")
        costs = np.sort([r["best_cost"] for r in recs[b] if r["n_nodes"] == n_max and r["noise"] == "per_step"])
        ax1.step(costs, np.arange(1, costs.size + 1) / costs.size, where="post", color=colour,
                 label=f"{b} ({costs.size} seeds)")
    ax0.axhline(0.75, color="k", lw=0.8, ls="--", label="issue 21 target")
    ax0.set_xticks(range(5))
    ax0.set(yscale="log", xlabel="planner seed", ylabel="CPU s per plan",
            title=f"IG-RRT* on paper-multi, N = {n_max}")
    ax0.legend(fontsize=8)
    ax1.set(xlabel="best cost (per step)", ylabel="fraction of seeds", title="cost distribution, same seeds")
    ax1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True, help="name of this record (e.g. before, after)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[500, 2000])
    ap.add_argument("--seeds", type=int, default=10, help="timed seeds 0..k-1 (default 10)")
    ap.add_argument("--cost-seeds", type=int, default=20, help="seeds of the N = max(sizes) cost distribution")
    ap.add_argument("--noise", nargs="+", default=["per_step"], choices=["per_step", "per_metre"])
    ap.add_argument("--baseline", type=Path, default=None,
                    help="folder holding the old belief_nlp package: run old and new alternately (paired)")
    ap.add_argument("--backends", nargs="+", default=None, choices=["numpy", "numba", "auto"],
                    help="run every case with each planner backend, alternately (paired)")
    ap.add_argument("--compile-cost", action="store_true",
                    help="first measure imports and first plan calls in fresh processes (numba cache empty / warm)")
    ap.add_argument("--only-compile-cost", action="store_true", help="--compile-cost alone, no planner runs")
    ap.add_argument("--out", type=Path, default=RESULTS / OUT_NAME)
    ap.add_argument("--plot", action="store_true",
                    help="only draw the records LABEL-numpy and LABEL-numba (a PNG next to the record)")
    args = ap.parse_args(argv)
    if args.plot:
        png = plot_backends(json.loads(args.out.read_text()), args.label,
                            args.out.with_name(f"planner_backends_{args.label}.png"))
        print(f"wrote {png}")
        return 0
    compile_record = compile_cost() if args.compile_cost or args.only_compile_cost else None
    if args.only_compile_cost:
        data = json.loads(args.out.read_text()) if args.out.exists() else {}
        data.setdefault("records", {})[f"{args.label}-compile"] = _finite({"machine": machine_info(),
                                                                           "first_calls": compile_record})
        args.out.write_text(json.dumps(data, indent=1, allow_nan=False))
        print(f"wrote {args.out}")
        return 0
    libs = {args.label: bn}
    kws: dict[str, dict] = {args.label: {}}
    if args.baseline is not None:
        pre = "" if args.label == "paired" else f"{args.label}-"
        libs = {f"{pre}before-paired": baseline_module(args.baseline), f"{pre}after-paired": bn}
        kws = {name: {} for name in libs}
    elif args.backends:
        libs = {f"{args.label}-{b}": bn for b in args.backends}
        kws = {f"{args.label}-{b}": {"backend": b} for b in args.backends}
    scs = {name: lib.load_scenario("paper-multi") for name, lib in libs.items()}
    for name, lib in libs.items():
        lib.plan(scs[name], n_nodes=200, seed=0, **kws[name])      # warm-up: imports, first-call caches
    info = machine_info()
    info["belief_nlp_file"] = {name: lib.__file__ for name, lib in libs.items()}
    runs: dict[str, list] = {name: [] for name in libs}
    t0 = time.perf_counter()
    n_max = max(args.sizes)
    for noise in args.noise:
        for n in args.sizes:
            for seed in range(max(args.seeds, args.cost_seeds) if n == n_max else args.seeds):
                for name, lib in libs.items():
                    rec = run_one(scs[name], n, seed, noise, lib, **kws[name])
                    runs[name].append(rec)
                    print(f"{name} {noise} N={n} seed={seed}: cost {rec['best_cost']:.6f}  wall {rec['wall_s']:.3f} s"
                          f"  cpu {rec['cpu_s']:.3f} s  load {rec['load_before'][0]:.2f}", flush=True)
    info["load_average_end"] = os.getloadavg()
    data = json.loads(args.out.read_text()) if args.out.exists() else {}
    data.setdefault("benchmark", "IG-RRT* speed on paper-multi (issue 21, item 6)")
    for name in libs:
        record = {"machine": info, "total_seconds": time.perf_counter() - t0,
                  "summary": summarise(runs[name], args.seeds), "runs": runs[name]}
        data.setdefault("records", {})[name] = _finite(record)
        for row in record["summary"]:
            print(name, json.dumps(row))
    if compile_record is not None:
        data["records"][f"{args.label}-compile"] = _finite({"machine": info, "first_calls": compile_record})
    recs = data["records"]
    if args.backends and len(args.backends) == 2:
        a, b = (f"{args.label}-{x}" for x in args.backends)
        data[f"{args.label}-backend_comparison"] = compare(recs[a], recs[b], paired=True)
    if "before" in recs and "after" in recs:
        data["comparison"] = compare(recs["before"], recs["after"])
    for name in recs:
        if name.endswith("before-paired") and name.replace("before-paired", "after-paired") in recs:
            pre = name[: -len("before-paired")]
            data[f"{pre}paired_comparison"] = compare(recs[name], recs[f"{pre}after-paired"], paired=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1, allow_nan=False))
    for key in [k for k in data if k.endswith("comparison")]:
        for row in data[key]:
            print(key, json.dumps(row))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
