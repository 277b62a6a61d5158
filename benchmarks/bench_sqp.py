"""SQP against IPOPT (issue 21 item 4: SQP within 10x IPOPT's wall time).

paper-multi, IG-RRT* plans with N = 500 nodes and per-step noise, alpha 0.1
and 1.0, K = 20 (seeds 0-4) and K = 40 (seeds 0-2); ``ipopt`` and ``sqp``
smooth the same warm start in one process after a warm-up call per (K,
method, alpha) (the NLPs and solvers are built then). SQP runs through the
interface given (``--interface``: unopy by default, ``casadi`` for CasADi's
plug-in) with a time limit of ``--cap`` times IPOPT's wall time on the same
case (a run that would take longer shows as ``time_limit``).

Per case: both methods' status, iterations, wall and CPU seconds, cost,
verified (``bn.verify``), the load average; the SQP / IPOPT wall ratio and
cost ratio. Summary per K: median and max wall ratio, cost ratios,
converged & verified. Writes benchmarks/results/sqp_vs_ipopt[_<interface>].json.

    python benchmarks/bench_sqp.py [--seeds 5 3] [--interface unopy] [--cap 30]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_nlp_speed import _case, _run  # noqa: E402 - the same warm starts and per-run record

import belief_nlp as bn  # noqa: E402
from belief_nlp.methods.sqp import UNO, UNOPY  # noqa: E402
from belief_nlp.methods.sqp_unopy import unopy_version  # noqa: E402

HERE = Path(__file__).resolve().parent / "results"


def _summary(rows: list[dict]) -> dict:
    wr = np.array([r["wall_ratio"] for r in rows])
    cr = np.array([r["cost_ratio"] for r in rows])
    return {"cases": len(rows),
            "sqp_converged_verified": sum(r["sqp"]["status"] == "converged" and r["sqp"]["verified"] for r in rows),
            "ipopt_converged_verified": sum(r["ipopt"]["status"] == "converged" and r["ipopt"]["verified"]
                                            for r in rows),
            "wall_ratio_median": float(np.median(wr)), "wall_ratio_max": float(np.max(wr)),
            "within_10x": int((wr <= 10).sum()),
            "cost_ratio_median": float(np.median(cr)), "cost_ratio_min": float(np.min(cr)),
            "cost_ratio_max": float(np.max(cr)),
            "sqp_median_iterations": float(np.median([r["sqp"]["iterations"] for r in rows])),
            "ipopt_median_iterations": float(np.median([r["ipopt"]["iterations"] for r in rows])),
            "sqp_median_wall_s": float(np.median([r["sqp"]["wall_s"] for r in rows])),
            "ipopt_median_wall_s": float(np.median([r["ipopt"]["wall_s"] for r in rows])),
            "sqp_median_ms_per_iteration": float(np.median([r["sqp"]["per_iteration_ms"] or np.nan for r in rows])),
            "median_loadavg": float(np.median([r["sqp"]["loadavg"] for r in rows]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=[5, 3], help="seeds at K = 20 and K = 40")
    ap.add_argument("--interface", default="unopy", choices=["unopy", "casadi"])
    ap.add_argument("--cap", type=float, default=30.0, help="SQP's time limit in multiples of IPOPT's wall")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    out = args.out or HERE / ("sqp_vs_ipopt.json" if args.interface == "unopy" else
                              f"sqp_vs_ipopt_{args.interface}.json")
    sc = bn.load_scenario("paper-multi")
    sqp_kw = {"interface": args.interface}
    res = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()},
           "settings": {"scenario": "paper-multi", "seeds": {"20": args.seeds[0], "40": args.seeds[1]},
                        "alpha": [0.1, 1.0], "nodes": 500, "noise": "per_step", "interface": args.interface,
                        "uno": unopy_version() if args.interface == "unopy" else "CasADi's 'uno' plug-in",
                        "uno_options": (UNOPY if args.interface == "unopy" else UNO).defaults,
                        "sqp_time_limit": f"{args.cap}x IPOPT wall on the same case"},
           "cases": [], "summary": {}}
    t0 = time.perf_counter()
    for K, n_seeds in zip((20, 40), args.seeds):
        cases = [(s, _case(sc, s, K)) for s in range(n_seeds)]
        cases = [(s, ws) for s, ws in cases if ws is not None]
        if not cases:
            continue
        for alpha in (0.1, 1.0):           # warm-up: build both stages' NLPs and solvers of this K
            bn.smooth(sc, cases[0][1], method="ipopt", alpha=alpha)
            bn.smooth(sc, cases[0][1], method="sqp", alpha=alpha, max_iter=2, **sqp_kw)
        rows = []
        for s, ws in cases:
            for alpha in (0.1, 1.0):
                ipo = _run(sc, ws, "ipopt", alpha)
                sqp = _run(sc, ws, "sqp", alpha, time_limit=max(args.cap * ipo["wall_s"], 1.0), **sqp_kw)
                row = {"seed": s, "K": K, "alpha": alpha, "ipopt": ipo, "sqp": sqp,
                       "wall_ratio": sqp["wall_s"] / ipo["wall_s"], "cost_ratio": sqp["cost"] / ipo["cost"]}
                rows.append(row)
                print(json.dumps({k: row[k] for k in ("seed", "K", "alpha", "wall_ratio", "cost_ratio")}
                                 | {m: {k: row[m][k] for k in ("status", "iterations", "wall_s", "cost", "verified",
                                                               "loadavg")} for m in ("ipopt", "sqp")}), flush=True)
        res["cases"] += rows
        res["summary"][f"K={K}"] = _summary(rows)
        print(f"K = {K}:", json.dumps(res["summary"][f"K={K}"]), flush=True)
        out.parent.mkdir(exist_ok=True)
        out.write_text(json.dumps(res, indent=1, default=float))
    res["wall_s"] = time.perf_counter() - t0
    res["machine"]["loadavg_at_end"] = os.getloadavg()
    out.write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
