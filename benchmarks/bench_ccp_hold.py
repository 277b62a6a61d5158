"""The active-set CCP step with and without the previous step's pairs held
(``belief_nlp.methods.ccp.HOLD_ACTIVE``), paired on the same starts.

Per case (paper-multi planner seeds 0..n-1 and random-polygons maps 0..n-1,
per-step N = 500 plans, alpha 0.1 and 1.0) both settings run in one process,
one after the other, from the same start:

* ``--mode ccp``: ``method="ccp"`` from the warm start (max_iter 100);
* ``--mode polish``: 10 CCP steps from IPOPT's answer, the polish that
  ``auto`` runs after IPOPT (K = 80 is where it costs most).

Records CPU seconds, steps, Clarabel solves' time, cost and verification per
case and setting; writes benchmarks/results/ccp_hold.json (one entry per run
of this script, keyed by K and mode).

    python benchmarks/bench_ccp_hold.py --K 20 --mode ccp --cases 3
    python benchmarks/bench_ccp_hold.py --K 80 --mode polish --cases 2
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.families import generate
from belief_nlp.methods import ccp

OUT = Path(__file__).resolve().parent / "results" / "ccp_hold.json"


def _starts(K: int, n: int):
    sc0 = bn.load_scenario("paper-multi")
    for s in range(n):
        for family, sc, seed in (("paper-multi", sc0, s), ("random-polygons", generate("random-polygons", s), 0)):
            plan = bn.plan(sc, n_nodes=500, seed=seed, noise="per_step")
            if plan.success:
                yield family, s, sc, bn.warm_start(sc, plan.path, K=K)


def _run(sc, start, alpha: float, hold: bool, max_iter: int) -> dict:
    ccp.HOLD_ACTIVE = hold
    load = os.getloadavg()[0]
    c = time.process_time()
    r = bn.smooth(sc, start, method="ccp", alpha=alpha, max_iter=max_iter)
    return {"cpu_s": time.process_time() - c, "cost": r.cost, "steps": r.nit, "status": r.status,
            "verified": bool(bn.verify(sc, r.path).safe), "clarabel_s": r.stats["solve_time"],
            "active_pairs": r.stats["active_pairs"], "loadavg": load}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--K", type=int, default=20)
    ap.add_argument("--mode", choices=("ccp", "polish"), default="ccp")
    ap.add_argument("--cases", type=int, default=3, help="seeds / maps 0..n-1 of each family")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    max_iter = 100 if args.mode == "ccp" else 10
    rows = []
    for family, s, sc, ws in _starts(args.K, args.cases):
        for alpha in (0.1, 1.0):
            start = ws if args.mode == "ccp" else bn.smooth(sc, ws, method="ipopt", alpha=alpha).path
            bn.smooth(sc, start, method="ccp", alpha=alpha, max_iter=1)         # build the step once
            runs = {str(hold): _run(sc, start, alpha, hold, max_iter) for hold in (False, True)}
            rows.append({"family": family, "seed": s, "alpha": alpha, "runs": runs})
            off, on = runs["False"], runs["True"]
            print(f"{family} {s} alpha {alpha}: CPU {off['cpu_s']:.2f} -> {on['cpu_s']:.2f} s, steps {off['steps']} -> "
                  f"{on['steps']}, cost ratio {on['cost'] / off['cost']:.7f}", flush=True)
    ccp.HOLD_ACTIVE = True
    cpu = [r["runs"]["True"]["cpu_s"] / r["runs"]["False"]["cpu_s"] for r in rows]
    cost = [r["runs"]["True"]["cost"] / r["runs"]["False"]["cost"] for r in rows]
    table = {"cases": len(rows), "median_cpu_ratio_held_to_not": float(np.median(cpu)),
             "total_cpu_s": {h: float(sum(r["runs"][h]["cpu_s"] for r in rows)) for h in ("False", "True")},
             "cost_ratio_median_min_max": [float(np.median(cost)), float(min(cost)), float(max(cost))],
             "verified": int(sum(r["runs"][h]["verified"] for r in rows for h in ("False", "True")))}
    print(json.dumps(table))
    doc = json.loads(args.out.read_text()) if args.out.exists() else {}
    doc[f"K={args.K},{args.mode}"] = {"cpus": os.cpu_count(), "command": vars(args) | {"out": str(args.out)},
                                      "table": table, "rows": rows}
    args.out.write_text(json.dumps(doc, indent=1, default=str))


if __name__ == "__main__":
    main()
