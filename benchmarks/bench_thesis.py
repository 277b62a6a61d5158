"""The paper's thesis, measured: plan with few nodes and smooth, or plan with many?

Runs the built-in study ``thesis`` (belief_nlp/study/builtin/thesis.toml):
IG-RRT* with N in {250, 500, 1000, 2000, 5000} (per-step noise) scored raw,
and N in {250, 500} followed by CCP, on paper-multi and two random maps,
alpha 0.1 and 1.0, every path on the smoother's objective at K = 20, each
path also simulated 2000 times (Monte-Carlo failure rate).

Writes the records under benchmarks/results/thesis/ (resumable: rerun to add
seeds), the summary benchmarks/results/thesis.json and the figure
benchmarks/results/thesis_cost_vs_time.png, and prints the verdict.

    python benchmarks/bench_thesis.py [--seeds 3] [--workers 2] [--fresh]
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

from belief_nlp import load_records
from belief_nlp.study import load_study, run_study, write_report

HERE = Path(__file__).resolve().parent / "results"


def _arm_label(row) -> str:
    n = int(row["planner_n_nodes"])
    return f"N={n}+{row['method']}" if row["method"] != "none" else f"N={n} raw"


def summarise(df) -> dict:
    """Paired comparisons per (scenario, seed, alpha): smoothed small-N plans against raw N = 5000."""
    df = df.copy()
    df["label"] = [_arm_label(r) for _, r in df.iterrows()]
    ok = df[df["safe"].astype(bool) & (df["K_used"] == 20)]
    groups = ["scenario", "seed", "alpha"]
    ref = ok[ok["label"] == "N=5000 raw"].set_index(groups)[["cost", "wall_time"]]
    arms = {}
    for label, g in ok.groupby("label"):
        g = g.set_index(groups)
        common = g.index.intersection(ref.index)
        arms[label] = {
            "paths": int(len(g)),
            "median_cost": float(g["cost"].median()),
            "median_wall_s": float(g["wall_time"].median()),
            "median_cost_over_raw5000": float(np.median(g.loc[common, "cost"] / ref.loc[common, "cost"]))
            if len(common) else None,
            "median_time_over_raw5000": float(np.median(g.loc[common, "wall_time"] / ref.loc[common, "wall_time"]))
            if len(common) else None,
            "mc_failure_rate": float(g["mc_failures"].sum() / g["mc_runs"].sum()) if g["mc_runs"].sum() else None,
        }
    per_alpha = {}
    for alpha, g in ok.groupby("alpha"):
        gi = g.set_index(groups)
        r5 = gi[gi["label"] == "N=5000 raw"]
        for label in ("N=500+ccp", "N=250+ccp", "N=1000 raw", "N=2000 raw", "N=500 raw"):
            s = gi[gi["label"] == label]
            common = s.index.intersection(r5.index)
            if len(common):
                per_alpha.setdefault(f"alpha={alpha:g}", {})[label] = {
                    "pairs": int(len(common)),
                    "median_cost_over_raw5000": float(np.median(s.loc[common, "cost"] / r5.loc[common, "cost"])),
                    "wins": int((s.loc[common, "cost"] < r5.loc[common, "cost"]).sum()),
                    "median_time_over_raw5000": float(np.median(s.loc[common, "wall_time"]
                                                                / r5.loc[common, "wall_time"]))}
    planned = df.drop_duplicates("case_key")
    return {"arms": arms, "per_alpha": per_alpha,
            "cases": int(planned["case_key"].nunique()),
            "plan_failed": int((planned["status"] == "plan_failed").sum()),
            "no_K20_warm_start": int(planned["warm_start_fallback"].astype(bool).sum()),
            "seeds": sorted(int(s) for s in df["seed"].unique())}


def figure(df, path: Path) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    df = df.copy()
    df["label"] = [_arm_label(r) for _, r in df.iterrows()]
    ok = df[df["safe"].astype(bool) & (df["K_used"] == 20)]
    alphas = sorted(ok["alpha"].unique())
    fig, axes = plt.subplots(1, len(alphas), figsize=(5 * len(alphas), 4), squeeze=False)
    for ax, alpha in zip(axes[0], alphas):
        g = ok[ok["alpha"] == alpha]
        ref = g[g["label"] == "N=5000 raw"].set_index(["scenario", "seed"])["cost"]
        for kind, marker in (("raw", "o"), ("ccp", "s")):
            pts = []
            for label, h in g.groupby("label"):
                if not label.endswith(kind):
                    continue
                h = h.set_index(["scenario", "seed"])
                common = h.index.intersection(ref.index)
                if not len(common):
                    continue
                pts.append((float(h.loc[common, "wall_time"].median()),
                            float(np.median(h.loc[common, "cost"] / ref.loc[common])), label))
            pts.sort()
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=marker,
                        label="IG-RRT* only" if kind == "raw" else "IG-RRT* + CCP smoothing")
                for x, y, lab in pts:
                    ax.annotate(lab.split("+")[0].replace(" raw", ""), (x, y), fontsize=7,
                                textcoords="offset points", xytext=(4, 4))
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())   # no crowded minor labels
        ax.set_xlabel("total wall time per path (plan + warm start + smoothing), s")
        ax.set_ylabel("cost / cost of raw N = 5000 plan (median)")
        ax.set_title(f"alpha = {alpha:g}")
        ax.axhline(1.0, color="grey", lw=0.5)
        ax.legend(fontsize=8)
    fig.suptitle("Cost versus total wall time (paper-multi and random maps)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="planner seeds 0..S-1")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--fresh", action="store_true", help="discard earlier records")
    ap.add_argument("--out", type=Path, default=HERE / "thesis")
    args = ap.parse_args()
    if args.fresh and args.out.exists():
        shutil.rmtree(args.out)
    study = load_study("thesis")
    study.seeds = list(range(args.seeds))
    load = os.getloadavg()
    t0 = time.perf_counter()
    run = run_study(study, args.out, workers=args.workers)
    elapsed = time.perf_counter() - t0
    df = load_records(args.out)
    keys = {c.key for c in study.cases()}     # this study's cases only (older records may share DIR)
    df = df[df["case_key"].isin(keys)]
    summary = summarise(df)
    figure(df, HERE / "thesis_cost_vs_time.png")
    write_report(args.out)
    out = {"what": "IG-RRT* N in {250..5000} raw vs N in {250, 500} + CCP (tol 1e-4), K = 20 objective",
           "machine": {"cpus": os.cpu_count(), "loadavg_at_start": load, "python": platform.python_version()},
           "run": {"cases_run_now": run.ran, "skipped": run.skipped, "seconds": elapsed, "executor": run.executor},
           **summary}
    (HERE / "thesis.json").write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
