"""Belief-space planning vs a standard planner, both followed by smoothing, at equal time.

Runs the built-in study ``baseline`` (belief_nlp/study/builtin/baseline.toml):
IG-RRT* and OMPL's RRT* (the mean path under the same exact transition checks,
then the least sensing that keeps it safe) each get the same planning budget
(3 s wall), on paper-multi and two random maps, alpha 0.1 and 1.0, seeds 0-2;
every plan is scored raw (its K = 20 warm start) and after the default
smoother (auto), on the smoother's K = 20 objective.

Writes the records under benchmarks/results/baseline/ (resumable), their OMPL
benchmark database benchmarks/results/baseline/baseline.db (Planner Arena),
the summary benchmarks/results/baseline.json (with the load average), the
figure benchmarks/results/baseline_paths.png (both planners once on
paper-multi, alpha 1, smoothed) and prints the table docs/studies.md shows.

    python benchmarks/bench_baseline.py [--seeds 3] [--workers 1] [--fresh]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np

from belief_nlp import export_ompl_benchmark, load_records
from belief_nlp.study import load_study, run_study, write_report

HERE = Path(__file__).resolve().parent / "results"
ARMS = {"igrrt": "IG-RRT*", "ompl:RRTstar": "OMPL RRT*"}


def _label(row) -> str:
    return f"{ARMS.get(row['planner_name'], row['planner_name'])} {'raw' if row['method'] == 'none' else '+ auto'}"


def summarise(df) -> dict:
    """Per (scenario kind, alpha): medians per arm and paired ratios against IG-RRT* + auto."""
    df = df.copy()
    df["label"] = [_label(r) for _, r in df.iterrows()]
    df["family"] = np.where(df["scenario"] == "paper-multi", "paper-multi", "random-polygons")
    ok = df[df["safe"].astype(bool) & (df["K_used"] == 20)]
    keys = ["scenario", "seed", "alpha"]
    out: dict = {}
    for (family, alpha), g in ok.groupby(["family", "alpha"]):
        gi = g.set_index(keys)
        ref = gi[gi["label"] == "IG-RRT* + auto"]
        arms = {}
        for label, h in gi.groupby("label"):
            common = h.index.intersection(ref.index)
            arms[label] = {
                "paths": int(len(h)),
                "median_cost": float(h["cost"].median()),
                "median_plan_time_s": float(h["plan_time"].median()),
                "median_total_time_s": float(h["wall_time"].median()),
                "pairs": int(len(common)),
                "median_cost_over_igrrt_auto": float(np.median(h.loc[common, "cost"] / ref.loc[common, "cost"]))
                if len(common) else None,
                # differences below 0.1 % are ties (the same local optimum, solver tolerance)
                "igrrt_auto_cheaper": int((ref.loc[common, "cost"] < h.loc[common, "cost"] * (1 - 1e-3)).sum()),
                "igrrt_auto_dearer": int((ref.loc[common, "cost"] > h.loc[common, "cost"] * (1 + 1e-3)).sum()),
            }
        out[f"{family}, alpha={alpha:g}"] = arms
    planned = df.drop_duplicates("case_key")
    by_planner = {}
    for name, g in planned.groupby("planner_name"):
        by_planner[name] = {"cases": int(len(g)), "plan_failed": int((g["status"] == "plan_failed").sum()),
                            "no_K20_warm_start": int(g["warm_start_fallback"].astype(bool).sum()),
                            "warm_start_failed": int((g["status"] == "warm_start_failed").sum())}
    return {"table": out, "planners": by_planner, "seeds": sorted(int(s) for s in df["seed"].unique())}


def table_markdown(summary: dict) -> str:
    """The docs/README table: median K = 20 cost (ratio to IG-RRT* + auto) and median total time."""
    labels = ["IG-RRT* raw", "IG-RRT* + auto", "OMPL RRT* raw", "OMPL RRT* + auto"]
    lines = ["| setting | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for setting, arms in summary["table"].items():
        cells = []
        for lab in labels:
            a = arms.get(lab)
            if a is None:
                cells.append("-")
                continue
            ratio = a["median_cost_over_igrrt_auto"]
            cells.append(f"{a['median_cost']:.3g} (x{ratio:.2f}), {a['median_total_time_s']:.1f} s"
                         if ratio is not None else f"{a['median_cost']:.3g}, {a['median_total_time_s']:.1f} s")
        lines.append(f"| {setting} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(path: Path, alpha: float = 1.0, budget: float = 3.0) -> dict:
    """Both planners once on paper-multi (seed 0), smoothed by auto: where the routes go."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import belief_nlp as bn
    from belief_nlp.plotting import plot_belief_path

    sc = bn.load_scenario("paper-multi").with_options(alpha=alpha)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5))
    out = {}
    for ax, (name, kw) in zip(axes, (("igrrt", {"n_nodes": 100000, "noise": "per_step"}), ("ompl:RRTstar", {}))):
        planned = bn.plan(sc, planner=name, time_limit=budget, alpha=alpha, **kw)
        res = bn.smooth(sc, planned.path, K=20, alpha=alpha)
        plot_belief_path(sc, res.path, ax=ax)
        ax.set_title(f"{ARMS[name]} ({budget:g} s) + auto: cost {res.cost:.3f}, "
                     f"{len(res.path.sensing_steps)} of 20 steps sense", fontsize=9)
        out[name] = {"cost": res.cost, "length": res.path.length, "sensing_steps": len(res.path.sensing_steps)}
    fig.suptitle(f"paper-multi, alpha = {alpha:g}, K = 20, {budget:g} s of planning each, smoothed by auto "
                 f"(one run each: the routes vary run to run)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="planner seeds 0..S-1")
    ap.add_argument("--workers", type=int, default=1, help="process-pool size (the machine is shared: 1)")
    ap.add_argument("--fresh", action="store_true", help="discard earlier records")
    ap.add_argument("--out", type=Path, default=HERE / "baseline")
    args = ap.parse_args()
    if args.fresh and args.out.exists():
        shutil.rmtree(args.out)
    study = load_study("baseline")
    study.seeds = list(range(args.seeds))
    load_start = os.getloadavg()
    t0 = time.perf_counter()
    run = run_study(study, args.out, workers=args.workers)
    elapsed = time.perf_counter() - t0
    load_end = os.getloadavg()
    df = load_records(args.out)
    keys = {c.key for c in study.cases()}
    df = df[df["case_key"].isin(keys)]
    summary = summarise(df)
    write_report(args.out)
    export_ompl_benchmark(df, args.out / "baseline.db")
    machine = {"cpus": os.cpu_count(), "loadavg_at_start": load_start, "loadavg_at_end": load_end,
               "python": platform.python_version()}
    ran = {"cases_run_now": run.ran, "skipped": run.skipped, "seconds": elapsed, "executor": run.executor}
    old = HERE / "baseline.json"
    if run.ran == 0 and old.exists():     # a re-summary: keep the figures of the run that measured
        before = json.loads(old.read_text())
        machine, ran = before.get("machine", machine), before.get("run", ran)
    example = figure(HERE / "baseline_paths.png")
    out = {"what": "IG-RRT* vs OMPL RRT* (mean path + least sensing), 3 s planning each, raw and + auto, "
                   "K = 20 objective; cost (xratio to IG-RRT* + auto, paired median), total time",
           "machine": machine, "run": ran,
           **summary, "example_paper_multi_alpha1_seed0": example, "markdown": table_markdown(summary)}
    (HERE / "baseline.json").write_text(json.dumps(out, indent=1))
    print(json.dumps({k: v for k, v in out.items() if k != "markdown"}, indent=1))
    print(out["markdown"])


if __name__ == "__main__":
    main()
