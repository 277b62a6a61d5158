"""A continuous-time collision budget (issue 20): what ``risk_kind="continuous"``
costs against the step-time budget, and whether its bound holds.

Grid: paper-multi (planner seed = seed) and the random-polygons family (map =
seed), seeds 0..S-1, alpha 0.1 / 1, Delta 0.05 / 0.1. Per case one plan
``bn.plan(sc, n_nodes=500, noise="per_step", risk=Delta)``, then ``auto`` at
K = 20 with the budget of each kind (optimal allocation). Per path: status,
cost, wall, the certified step-time and continuous-time bounds recomputed by
``belief_nlp.risk.path_risk`` (the exact continuous formula), the surrogate
sum the model spent (``continuous_surrogate``), and for the continuous kind a
closed-loop Monte-Carlo rate of touching a hazard at any sampled instant
(``--runs`` runs, 40 samples per transition; 95 % Clopper-Pearson lower end
against the bound). A case whose warm start cannot meet the budget is an
error row with the smoother's message.

Writes benchmarks/results/risk_continuous.json and prints the table.

    python benchmarks/bench_risk_continuous.py [--seeds 5] [--runs 4000] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

from _record import run_and_record

OUT = Path(__file__).resolve().parent / "results" / "risk_continuous.json"


def run_case(case: dict) -> dict:
    warnings.simplefilter("ignore")
    import belief_nlp as bn
    from belief_nlp.families import generate
    from belief_nlp.risk import continuous_surrogate, path_risk
    from belief_nlp.study.montecarlo import clopper_pearson, simulate

    sc, pseed = ((bn.load_scenario("paper-multi"), case["seed"]) if case["kind"] == "paper-multi"
                 else (generate("random-polygons", case["seed"]), 0))
    sc = sc.with_options(alpha=case["alpha"])
    out = dict(case, load=os.getloadavg()[0])
    plan = bn.plan(sc, n_nodes=500, seed=pseed, noise="per_step", risk=case["delta"])
    if plan.path is None:
        return dict(out, error=f"no plan: {plan.message}")
    for kind in ("steps", "continuous"):
        t = time.perf_counter()
        try:
            r = bn.smooth(sc, plan.path, K=20, k_fallback=False, risk=case["delta"], risk_kind=kind)
        except bn.BeliefNLPError as exc:
            out[kind] = {"error": str(exc)[:200]}
            continue
        wall = time.perf_counter() - t
        rb = path_risk(sc, r.path, r.certificates)
        rec = {"status": r.status, "cost": r.cost, "wall": wall, "step_time": rb.step_time,
               "continuous": rb.continuous, "surrogate": float(np.sum(continuous_surrogate(sc, r.path))),
               "verified": bool(bn.verify(sc, r).safe)}
        if kind == "continuous":
            mc = simulate(sc, r.path, runs=case["runs"], substeps=40, seed=case["seed"])
            lo, hi = clopper_pearson(mc.hazard_runs, mc.runs)
            rec.update(mc_rate=mc.hazard_runs / mc.runs, mc_lo=lo, mc_hi=hi)
        out[kind] = rec
    return out


def summarise(rows: list[dict]) -> dict:
    ok = [r for r in rows if "steps" in r and "continuous" in r and "error" not in r["steps"]
          and "error" not in r["continuous"]]
    table = {}
    for d in sorted({r["delta"] for r in rows}):
        for a in sorted({r["alpha"] for r in rows}):
            sel = [r for r in ok if r["delta"] == d and r["alpha"] == a]
            cases = [r for r in rows if r["delta"] == d and r["alpha"] == a]
            if not sel:
                continue
            c, s = [r["continuous"] for r in sel], [r["steps"] for r in sel]
            table[f"delta={d}/alpha={a}"] = {
                "cases": len(cases), "both_solved": len(sel),
                "errors": [r.get("error") or r["continuous"].get("error") or r["steps"].get("error")
                           for r in cases if r not in sel],
                "continuous_converged_verified": sum(x["status"] == "converged" and x["verified"] for x in c),
                "continuous_bound_max": float(max(x["continuous"] for x in c)),
                "continuous_bound_median": float(np.median([x["continuous"] for x in c])),
                "surrogate_max": float(max(x["surrogate"] for x in c)),
                "steps_kind_continuous_bound_median": float(np.median([x["continuous"] for x in s])),
                "steps_kind_over_budget": sum(x["continuous"] > d for x in s),
                "cost_continuous_over_steps_median": float(np.median([x["cost"] / y["cost"] for x, y in zip(c, s)])),
                "wall_continuous_over_steps_median": float(np.median([x["wall"] / y["wall"] for x, y in zip(c, s)])),
                "mc_refutes": sum(x["mc_lo"] > x["continuous"] for x in c),
                "mc_rate_over_bound_median": float(np.median([x["mc_rate"] / x["continuous"] for x in c])),
            }
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--runs", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    cases = [dict(kind=k, seed=s, alpha=al, delta=d, runs=a.runs) for k in ("paper-multi", "random-polygons")
             for s in range(a.seeds) for al in (0.1, 1.0) for d in (0.05, 0.1)]
    run_and_record(run_case, cases, summarise, a, a.out, a.workers)


if __name__ == "__main__":
    main()
