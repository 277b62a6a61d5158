"""IPOPT under an optimal risk budget: its two stages, iteration by iteration.

Under ``risk=Delta`` (``allocation="optimal"``) the NLP holds one level per
transition-hazard pair. The exact-Cholesky polish switches off the sensing
the first stage held at its floor; this script measures what that polish
costs and whether it converges (docs/numerics.md, "Risk allocation in the
NLP polish").

Protocol: paper-multi seeds and random-polygons maps 0..n-1 (planner seed
0), alpha 0.1 and 1.0, Delta 0.05 and 0.25, an IG-RRT* plan per (map,
seed, alpha) (N = 500, per-step noise) smoothed at K = 20 (no fallback to
one step per edge) by ``--method`` (default ipopt). A plan without a warm
start inside the budget is an error row with its message. Per case: status,
iterations of each IPOPT stage and the polish's return status, cost, CPU
seconds, whether the answer verifies. Two worker processes.

    python benchmarks/bench_risk_nlp.py [--seeds 10] [--method ipopt] [--kind steps] [--out FILE]

``--kind continuous`` budgets the continuous-time bound instead (its
warm start sharpens every posterior: docs/numerics.md).
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
from belief_nlp.families import generate

HERE = Path(__file__).resolve().parent / "results"
ALPHAS = (0.1, 1.0)
DELTAS = (0.05, 0.25)


def _scenario(family: str, seed: int) -> bn.Scenario:
    return bn.load_scenario("paper-multi") if family == "paper-multi" else generate(family, seed)


def _case(spec: dict) -> list[dict]:
    """Every (alpha, Delta) of one map: one plan per alpha, shared by the Deltas."""
    warnings.filterwarnings("ignore")
    family, seed, method, kind = spec["family"], spec["seed"], spec["method"], spec["kind"]
    sc = _scenario(family, seed)
    rows = []
    for alpha in ALPHAS:
        plan = bn.plan(sc, n_nodes=500, seed=seed if family == "paper-multi" else 0, alpha=alpha,
                       noise="per_step")
        for delta in DELTAS:
            row = {"family": family, "seed": seed, "alpha": alpha, "delta": delta, "method": method, "kind": kind}
            t0 = cpu_seconds()
            try:
                res = bn.smooth(sc, plan, K=20, alpha=alpha, method=method, risk=delta, risk_kind=kind,
                                k_fallback=False)
            except bn.BeliefNLPError as exc:
                rows.append(row | {"status": "error", "error": str(exc)[:200]})
                continue
            attempts = res.stats.get("attempts", []) if isinstance(res.stats, dict) else []
            stages = {a["formulation"]: a for a in attempts}
            polish = stages.get("cholesky", {})
            rows.append(row | {
                "status": res.status, "iterations": res.nit, "cpu_s": cpu_seconds() - t0, "cost": res.cost,
                "verified": bool(bn.verify(sc, res).safe and res.risk.budget == delta),
                "stage1_iterations": stages.get("logchol", {}).get("iter_count"),
                "polish_iterations": polish.get("iter_count"), "polish_status": polish.get("return_status"),
                "message": res.message})
    return rows


def _summary(records: list[dict]) -> dict:
    ok = [r for r in records if r["status"] != "error"]
    table = {}
    for alpha in ALPHAS:
        rows = [r for r in ok if r["alpha"] == alpha]
        pol = [r for r in rows if r.get("polish_status")]
        table[f"alpha {alpha:g}"] = {
            "cases": len(rows),
            "converged and verified": sum(r["status"] == "converged" and r["verified"] for r in rows),
            "median iterations": float(np.median([r["iterations"] for r in rows])) if rows else None,
            "median CPU s": float(np.median([r["cpu_s"] for r in rows])) if rows else None,
            "total CPU s": float(sum(r["cpu_s"] for r in rows)),
        }
        if pol:     # IPOPT's stages (method "ipopt"; auto's statistics hold no attempts)
            table[f"alpha {alpha:g}"] |= {
                "median polish iterations": float(np.median([r["polish_iterations"] for r in pol])),
                "polishes converged": f"{sum(r['polish_status'] == 'Solve_Succeeded' for r in pol)}/{len(pol)}"}
    table["errors (no warm start within the budget)"] = len(records) - len(ok)
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="paper-multi seeds and random-polygons maps 0..n-1")
    ap.add_argument("--method", default="ipopt")
    ap.add_argument("--kind", default="steps", choices=("steps", "continuous"), help="the budget's risk_kind")
    ap.add_argument("--out", type=Path, default=HERE / "risk_nlp.json")
    args = ap.parse_args()
    specs = [{"family": f, "seed": s, "method": args.method, "kind": args.kind}
             for f in ("paper-multi", "random-polygons") for s in range(args.seeds)]
    t0, load0 = time.time(), os.getloadavg()
    with ProcessPoolExecutor(2) as ex:                 # a list of rows per map
        records = [row for rows in ex.map(_case, specs) for row in rows]
    write_record(args.out, args, _summary(records), records, t0, load0)

if __name__ == "__main__":
    main()
