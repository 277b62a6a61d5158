"""IG-RRT*'s rewiring cap in 3-D: how often cube3d plans, by ``radius_per_alpha``.

Under per-step noise the cap of the rewiring radius grows with alpha,
cap = max_radius + radius_per_alpha * alpha, because an unsensed step costs
alpha/2 log det(I + W P^-1) whatever its length. The default 1.2 was
tuned in 2-D on paper-multi. That information cost is a sum over the d
directions, so a 3-D edge costs more, and cube3d at alpha = 1 planned few
seeds (docs/planner.md, "The cap in 3-D").

Protocol: cube3d at the scenario's N (500), per-step noise, planner seeds
0..n-1, alpha 0.1, 0.5 and 1, radius_per_alpha 1.2, 1.8, 2.4 and 3.6 (set
explicitly, so the scenario file's own value does not enter). Per run:
success, cost, edges, CPU seconds. Two worker processes.

    python benchmarks/bench_planner_cap.py [--seeds 16] [--out FILE]
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import belief_nlp as bn
from _record import run_and_record

HERE = Path(__file__).resolve().parent / "results"
CAPS = (1.2, 1.8, 2.4, 3.6)
ALPHAS = (0.1, 0.5, 1.0)


def _run(spec: dict) -> dict:
    warnings.filterwarnings("ignore")
    sc = bn.load_scenario("cube3d")
    t0 = time.process_time()
    res = bn.plan(sc, seed=spec["seed"], alpha=spec["alpha"], radius_per_alpha=spec["radius_per_alpha"])
    return spec | {"success": bool(res.success), "cost": float(res.cost) if res.success else None,
                   "edges": int(res.path.K) if res.success else None, "cpu_s": time.process_time() - t0}


def _summary(records: list[dict]) -> dict:
    table = {}
    for cap in CAPS:
        for alpha in ALPHAS:
            rows = [r for r in records if r["radius_per_alpha"] == cap and r["alpha"] == alpha]
            ok = [r for r in rows if r["success"]]
            table[f"radius_per_alpha {cap:g}, alpha {alpha:g}"] = {
                "planned": f"{len(ok)}/{len(rows)}",
                "median cost": float(np.median([r["cost"] for r in ok])) if ok else None,
                "median edges": float(np.median([r["edges"] for r in ok])) if ok else None,
                "total CPU s": round(float(sum(r["cpu_s"] for r in rows)), 2)}
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--out", type=Path, default=HERE / "planner_cap_3d.json")
    args = ap.parse_args()
    cases = [{"radius_per_alpha": c, "alpha": a, "seed": s} for c in CAPS for a in ALPHAS for s in range(args.seeds)]
    run_and_record(_run, cases, _summary, args, args.out, workers=2)


if __name__ == "__main__":
    main()
