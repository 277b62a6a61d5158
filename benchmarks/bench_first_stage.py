"""First-stage solver options against the defaults on the issue-21 protocol.

The warm starts of ``bench_nlp_speed.py`` (paper-multi planner seeds and
random-polygons maps, per-step N = 500 plans), both alphas, one K; each
variant is a ``first_stage_options`` dict given to ``auto`` (through
``ipopt_options``) or to ``ipopt``. Every map is warmed up per variant (its
NLP and solvers built) before its cases are timed, in one process. Per case:
iterations, wall seconds, cost, verified; per variant: medians, and the cost
ratio to the first variant's per case. Writes a JSON record (the load
average next to every case: the machine is shared).

    python benchmarks/bench_first_stage.py --K 40 --seeds 10 [--first 0] [--method auto]
        [--variants '{"defaults": {}, "mu_min 3e-6": {"mu_min": 3e-6}}'] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn

from bench_nlp_speed import _case, _run, _scenarios

HERE = Path(__file__).resolve().parent / "results"


def _kw(method: str, options: dict) -> dict:
    """The smooth() keywords that hand ``options`` to ``method``'s first stage."""
    return {"ipopt_options": {"first_stage_options": options}} if method == "auto" else {"first_stage_options": options}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--K", type=int, default=40)
    ap.add_argument("--seeds", type=int, default=10, help="seeds (and maps) per family")
    ap.add_argument("--first", type=int, default=0, help="first seed (and map)")
    ap.add_argument("--method", default="auto", choices=["auto", "ipopt"])
    ap.add_argument("--variants", default='{"defaults": {}, "mu_min 3e-6": {"mu_min": 3e-6}}')
    ap.add_argument("--out", type=Path, default=HERE / "first_stage.json")
    args = ap.parse_args()
    variants = json.loads(args.variants)
    cases = []
    for fam in ("paper-multi", "random-polygons"):
        for s, sc, plan_seed in _scenarios(fam, args.first + args.seeds)[args.first:]:
            ws = _case(sc, plan_seed, args.K)
            if ws is not None:
                cases.append((fam, s, sc, ws))
    res = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()},
           "settings": {"K": args.K, "seeds": list(range(args.first, args.first + args.seeds)), "method": args.method,
                        "variants": variants}, "cases": {}, "summary": {}}
    t0 = time.perf_counter()
    for name, options in variants.items():
        rows, warmed = [], set()
        for fam, s, sc, ws in cases:
            if id(sc) not in warmed:
                for a in (0.1, 1.0):
                    bn.smooth(sc, ws, method=args.method, alpha=a, **_kw(args.method, options))
                warmed.add(id(sc))
            for a in (0.1, 1.0):
                # bench_nlp_speed's record of a call (wall, CPU, iterations, cost, verified by bn.verify)
                rows.append({"family": fam, "seed": s, "alpha": a,
                             **_run(sc, ws, args.method, a, **_kw(args.method, options))})
        res["cases"][name] = rows
        its, wall = [x["iterations"] for x in rows], [x["wall_s"] for x in rows]
        summary = {"cases": len(rows), "median_iterations": float(np.median(its)), "total_iterations": int(sum(its)),
                   "median_wall_s": float(np.median(wall)), "total_wall_s": float(sum(wall)),
                   "converged_and_verified": sum(x["status"] == "converged" and x["verified"] for x in rows)}
        base = res["cases"][next(iter(variants))]
        if rows is not base:
            ratio = np.array([b["cost"] / a["cost"] for a, b in zip(base, rows)])
            wr = np.array([b["wall_s"] / a["wall_s"] for a, b in zip(base, rows)])
            summary.update(cost_ratio_min=float(ratio.min()), cost_ratio_median=float(np.median(ratio)),
                           cost_ratio_max=float(ratio.max()), above_0_1_percent=int((ratio > 1.001).sum()),
                           below_0_1_percent=int((ratio < 0.999).sum()), wall_ratio_median=float(np.median(wr)))
        res["summary"][name] = summary
        print(name, json.dumps(summary), flush=True)
        args.out.parent.mkdir(exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1))
    res["wall_s"] = time.perf_counter() - t0
    res["machine"]["loadavg_at_end"] = os.getloadavg()
    args.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
