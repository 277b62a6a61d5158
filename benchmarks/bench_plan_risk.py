"""IG-RRT* within an end-to-end collision budget (issue 20, item 3): what
``plan(scenario, risk=Delta)`` certifies and what it costs.

For each budget Delta (and no budget: the scenario's fixed chi2) and seeds
0..``--seeds``-1 on paper-multi (N = ``--nodes``), with its horizon K = 20
(the smoother's K, so round 1 plans at the level of 20 J pairs) and without
(one smoother step per path edge: rounds follow the paths' edges), one record: success, the
certified step-time bound recomputed from the path
(``belief_nlp.risk.path_risk``), the planner's collision level, the rounds,
the path's K, planner cost, travel and information, the wall time and the
load average. The summary per budget gives the success count, the largest
bound / budget ratio (<= 1 by construction), the median bound and cost and
the rounds used.

    PYTHONPATH=$PWD python benchmarks/bench_plan_risk.py
    -> benchmarks/results/plan_risk.json
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import belief_nlp as bn  # noqa: E402
from belief_nlp.risk import path_risk  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_planner import _finite, machine_info, median  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "plan_risk.json"
BUDGETS = (None, 0.25, 0.1, 0.05, 0.01)


def one(sc, budget, seed: int, nodes: int) -> dict:
    """One plan and what it certifies."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    res = bn.plan(sc, n_nodes=nodes, seed=seed, risk=budget)
    wall = time.perf_counter() - t0
    rec = {"horizon": sc.K, "budget": budget, "seed": seed, "nodes": nodes, "success": res.success, "wall_s": wall,
           "load_average": load, "message": res.message}
    if res.success:
        rec.update(bound=path_risk(sc, res.path).step_time, K=res.path.K, cost=res.cost, travel=res.travel,
                   information=res.information)
    if res.risk is not None:
        rec.update(collision_chi2=res.risk["collision_chi2"], rounds=len(res.risk["rounds"]))
    else:
        rec.update(collision_chi2=sc.chi2, rounds=1)
    return rec


def summary(records: list[dict]) -> list[dict]:
    """Per horizon and budget: successes, bounds, costs, levels, rounds."""
    out = []
    for horizon, budget in sorted({(r["horizon"] or 0, r["budget"] or 1) for r in records}, reverse=True):
        rs = [r for r in records if (r["horizon"] or 0, r["budget"] or 1) == (horizon, budget)]
        budget = rs[0]["budget"]
        ok = [r for r in rs if r["success"]]
        out.append({
            "horizon": rs[0]["horizon"], "budget": budget, "runs": len(rs), "success": len(ok),
            "max_bound_over_budget": (max(r["bound"] / budget for r in ok) if ok and budget else None),
            "median_bound": median([r["bound"] for r in ok]), "max_bound": max((r["bound"] for r in ok), default=None),
            "median_cost": median([r["cost"] for r in ok]), "median_K": median([r["K"] for r in ok]),
            "collision_chi2": sorted({round(r["collision_chi2"], 4) for r in rs}),
            "rounds": sorted({r["rounds"] for r in rs}), "median_wall_s": median([r["wall_s"] for r in rs]),
        })
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--nodes", type=int, default=500)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    sc = bn.load_scenario("paper-multi")
    machine = machine_info()
    records = [one(s, budget, seed, a.nodes) for s in (sc, sc.with_options(K=None)) for budget in BUDGETS
               for seed in range(a.seeds)]
    machine["load_average_end"] = os.getloadavg()
    table = summary(records)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(_finite({"scenario": "paper-multi", "machine": machine, "summary": table,
                                         "records": records}), indent=1))
    for row in table:
        print(row)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
