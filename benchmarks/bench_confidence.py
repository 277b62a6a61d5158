"""The NLP methods at the confidence levels users set: 0.9 (the built-in
scenarios'), 0.99, 0.995 and 0.999.

A higher level widens every collision ellipse: on ``tutorial``'s narrow
passage the path must sense hard, and IPOPT's first attempt from the planner's
start ran into Infeasible_Problem_Detected or Invalid_Number_Detected on 12 of
52 cases before the restart inside the Kalman box (docs/numerics.md,
"The Kalman box").

Protocol: ``tutorial`` (planner seeds 0..n-1 at the scenario's N, K = 6, 8,
10 and 12), ``paper-multi`` (seeds 0..n-1, N = 500, per-step noise,
K = 20) and ``cube3d`` (``--cube3d``: seeds 0..n-1 at the scenario's N,
the plan's own steps (K None), K = 10 and 14), alpha 0.1 and 1.0, one plan per (scenario, seed, alpha, level)
planned at that level. A plan longer than K edges is an error row (no
fallback to one step per edge). Per case: status, the solver's attempts
(return status and iterations), cost, CPU seconds, whether the answer
verifies. Two worker processes.

    python benchmarks/bench_confidence.py [--seeds 5] [--method ipopt] [--cube3d] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import belief_nlp as bn
from _record import cpu_seconds, write_record

HERE = Path(__file__).resolve().parent / "results"
LEVELS = (0.9, 0.99, 0.995, 0.999)
ALPHAS = (0.1, 1.0)
#: the solvers' own statuses of a converged attempt (IPOPT's, Uno's)
SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Converged with feasible KKT point")
HORIZONS = {"tutorial": (6, 8, 10, 12), "paper-multi": (20,), "cube3d": (None, 10, 14)}


def _case(spec: dict) -> list[dict]:
    """Every (alpha, K) of one (scenario, seed, level)."""
    warnings.filterwarnings("ignore")
    name, seed, level, method = spec["scenario"], spec["seed"], spec["level"], spec["method"]
    sc = bn.load_scenario(name).with_options(confidence=level)
    plan_kw = {"n_nodes": 500, "noise": "per_step"} if name == "paper-multi" else {}
    rows = []
    for alpha in ALPHAS:
        plan = bn.plan(sc, seed=seed, alpha=alpha, **plan_kw)
        for K in HORIZONS[name]:
            row = {"scenario": name, "seed": seed, "level": level, "chi2": sc.chi2, "alpha": alpha, "K": K,
                   "method": method}
            if not plan.success:
                rows.append(row | {"status": "error", "error": "no plan"})
                continue
            t0 = cpu_seconds()
            try:
                res = bn.smooth(sc, plan, K=K, alpha=alpha, method=method, k_fallback=False)
            except bn.BeliefNLPError as exc:
                rows.append(row | {"status": "error", "error": str(exc)[:200]})
                continue
            attempts = res.stats.get("attempts", []) if isinstance(res.stats, dict) else []
            rows.append(row | {
                "status": res.status, "iterations": res.nit, "cpu_s": cpu_seconds() - t0, "cost": res.cost,
                "start_cost": res.initial_cost, "verified": bool(res.safe and bn.verify(sc, res.path).safe),
                "attempts": [(a["return_status"], a["iter_count"]) for a in attempts], "message": res.message})
    return rows


def _summary(records: list[dict]) -> dict:
    table = {}
    for name in HORIZONS:
        for level in LEVELS:
            rows = [r for r in records if r["scenario"] == name and r["level"] == level and r["status"] != "error"]
            if not rows:
                continue
            table[f"{name} {level:g}"] = {
                "cases": len(rows),
                "converged and verified": sum(r["status"] == "converged" and r["verified"] for r in rows),
                "first attempt failed": sum(bool(r["attempts"]) and r["attempts"][0][0] not in SUCCESS for r in rows),
                "median iterations": float(np.median([r["iterations"] for r in rows])),
                "total iterations": int(sum(r["iterations"] for r in rows)),
                "total CPU s": round(float(sum(r["cpu_s"] for r in rows)), 2),
            }
    table["errors (plan longer than K, or no plan)"] = sum(r["status"] == "error" for r in records)
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="planner seeds 0..n-1 per scenario")
    ap.add_argument("--method", default="ipopt")
    ap.add_argument("--cube3d", action="store_true", help="also the 3-D scenario cube3d")
    ap.add_argument("--out", type=Path, default=HERE / "confidence.json")
    args = ap.parse_args()
    names = [n for n in HORIZONS if n != "cube3d" or args.cube3d]
    specs = [{"scenario": name, "seed": s, "level": level, "method": args.method}
             for name in names for level in LEVELS for s in range(args.seeds)]
    t0, load0 = time.time(), os.getloadavg()
    with ProcessPoolExecutor(2) as ex:                 # a list of rows per (scenario, seed, level)
        records = [row for rows in ex.map(_case, specs) for row in rows]
    write_record(args.out, args, _summary(records), records, t0, load0)


if __name__ == "__main__":
    main()
