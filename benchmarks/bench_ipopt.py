"""IPOPT ablation (issue 10, item 2; docs/numerics.md, "IPOPT iterations").

paper-multi, K = 20, per-step IG-RRT* warm starts (N = 500), seeds and both
alphas; each variant changes the defaults of ``method="ipopt"`` by options
only. Records per case: IPOPT iterations (all stages), restoration
iterations, solver CPU seconds, final cost, verified. Writes
benchmarks/results/ipopt_ablation.json.

    python benchmarks/bench_ipopt.py [--seeds 5] [--K 20]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.methods import ipopt

HERE = Path(__file__).resolve().parent / "results"

VARIANTS = {
    "before: Cholesky NLP, adaptive mu (the previous default)": dict(formulation="cholesky", polish=0),
    "log-Cholesky floored at 1e-2, adaptive mu, no polish": dict(polish=0, solver_options={"mu_min": 1e-11}),
    "+ mu_min 1e-7": dict(polish=0),
    "+ polish (the default)": dict(),
    "log-Cholesky, monotone mu, + polish": dict(solver_options={"mu_strategy": "monotone", "mu_min": 1e-11}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--K", type=int, default=20)
    args = ap.parse_args()
    load = os.getloadavg()
    sc = bn.load_scenario("paper-multi")
    plans = {s: bn.plan(sc, n_nodes=500, seed=s, noise="per_step").path for s in range(args.seeds)}
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": load}, "settings": vars(args), "variants": []}
    for name, kw in VARIANTS.items():
        ipopt.clear_cache()
        rows = []
        for s, path in plans.items():
            for alpha in (0.1, 1.0):
                r = bn.smooth(sc, path, method="ipopt", K=args.K, alpha=alpha, **kw)
                att = r.stats.get("attempts", [])
                rows.append({"seed": s, "alpha": alpha, "status": r.status, "cost": r.cost,
                             "iterations": int(r.stats.get("iter_count", 0)),
                             "restoration": int(sum(a["restoration"] for a in att)),
                             "cpu_s": float(sum(a["cpu_time"] for a in att)), "verified": r.safe,
                             "polish": r.stats.get("polish_status", "")})
        its = [x["iterations"] for x in rows]
        out["variants"].append({"name": name, "options": kw, "median_iterations": float(np.median(its)),
                                "max_iterations": int(max(its)),
                                "median_cpu_s": float(np.median([x["cpu_s"] for x in rows])),
                                "converged": sum(x["status"] == "converged" for x in rows),
                                "verified": sum(bool(x["verified"]) for x in rows), "cases": len(rows), "rows": rows})
        v = out["variants"][-1]
        print(f"{name}: median {v['median_iterations']} (max {v['max_iterations']}) iterations, "
              f"{v['median_cpu_s']:.2f} s CPU, {v['converged']}/{v['cases']} converged, "
              f"{v['verified']}/{v['cases']} verified; costs {[round(x['cost'], 4) for x in rows]}", flush=True)
    # cost relative to the best of all variants per case
    best = {}
    for v in out["variants"]:
        for x in v["rows"]:
            key = (x["seed"], x["alpha"])
            best[key] = min(best.get(key, np.inf), x["cost"])
    for v in out["variants"]:
        v["max_cost_ratio_to_best"] = float(max(x["cost"] / best[(x["seed"], x["alpha"])] for x in v["rows"]))
    out["machine"]["loadavg_at_end"] = os.getloadavg()
    out["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    HERE.mkdir(exist_ok=True)
    (HERE / "ipopt_ablation.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
