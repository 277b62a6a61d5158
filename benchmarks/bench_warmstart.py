"""Warm starts at a requested K from safe IG-RRT* plans (issue 10, item 4).

For every seed: plan with per-step noise (N nodes) on paper-multi and on
random-polygons maps; for each safe plan, build the warm start at K (default
20) and record whether the step allocation kept every sub-transition clear
(success at K), fell back (and to which K), or failed. Writes
benchmarks/results/warmstart.json.

    python benchmarks/bench_warmstart.py [--seeds 50] [--nodes 500] [--K 20]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.errors import InfeasibleStartError
from belief_nlp.families import generate

HERE = Path(__file__).resolve().parent / "results"


def _one(sc, seed: int, nodes: int, K: int) -> dict:
    t = time.perf_counter()
    plan = bn.plan(sc, n_nodes=nodes, seed=seed, noise="per_step")
    row = {"scenario": sc.name, "seed": seed, "plan_success": bool(plan.success),
           "plan_time": time.perf_counter() - t}
    if not plan.success:
        return row
    row["edges"] = int(plan.path.K)
    t = time.perf_counter()
    try:
        ws = bn.warm_start(sc, plan.path, K=K)
        row.update(outcome="at_K", K=int(ws.K))
    except InfeasibleStartError as exc:
        row.update(outcome="infeasible", error=str(exc)[:300])
    row["warm_start_time"] = time.perf_counter() - t
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--nodes", type=int, default=500)
    ap.add_argument("--K", type=int, default=20)
    ap.add_argument("--maps", type=int, default=10, help="random-polygons maps (seeds are spread over them)")
    args = ap.parse_args()
    load = os.getloadavg()
    rows = []
    scenarios = [bn.load_scenario("paper-multi")] + [generate("random-polygons", m) for m in range(args.maps)]
    for seed in range(args.seeds):
        rows.append(_one(scenarios[0], seed, args.nodes, args.K))
        rows.append(_one(scenarios[1 + seed % args.maps], seed, args.nodes, args.K))
        print(json.dumps(rows[-2]), json.dumps(rows[-1]), flush=True)
    summary = {}
    for fam in ("paper-multi", "random-polygons"):
        rs = [r for r in rows if r["scenario"].startswith(fam) and r["plan_success"]]
        ok = sum(r["outcome"] == "at_K" for r in rs)
        summary[fam] = {"safe_plans": len(rs), "at_K": ok, "rate": ok / max(1, len(rs)),
                        "median_edges": float(np.median([r["edges"] for r in rs])) if rs else None}
    res = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": load, "loadavg_at_end": os.getloadavg()},
           "settings": vars(args), "summary": summary, "rows": rows}
    HERE.mkdir(exist_ok=True)
    (HERE / "warmstart.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
