"""Stress sweep: fresh maps of the scenario families, every method, with and
without a risk budget; every returned path checked by ``bn.verify`` (at its
own levels and against the budget when there is one).

Nothing here is timed against a target: the record lists what each case
returned (status, verified, cost against the warm start, wall, the
certified bound) so that a failure -- an exception, an unverified path, a
bound above the budget, a run that ends on its warm start -- can be found
and reproduced by (family, map, method, ...). Each case plans its map
itself (IG-RRT*, N = 500, per-step noise, seed 0).

    python benchmarks/bench_stress.py --families random-polygons:40-50 corridor:20-30 \\
        --methods auto ccp fatrop sqp --budget 0.05 --out benchmarks/results/stress_budget.json
    python benchmarks/bench_stress.py --families boxes3d:20-28 --methods auto fatrop sqp ccp \\
        --alphas 0.1 1.0 --out benchmarks/results/stress_plain.json
"""

from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path

from _record import run_and_record

RESULTS = Path(__file__).parent / "results"


def _maps(spec: str) -> list[tuple[str, int]]:
    """"family:a-b" -> [(family, a), ..., (family, b - 1)]."""
    fam, _, rng = spec.partition(":")
    lo, _, hi = rng.partition("-")
    return [(fam, m) for m in range(int(lo), int(hi))]


def run_case(case: dict) -> dict:
    import belief_nlp as bn
    from belief_nlp.families import generate

    rec = dict(case)
    sc = generate(case["family"], case["map"])
    budget = case.get("budget")
    try:
        plan = bn.plan(sc, n_nodes=500, seed=0, noise="per_step", **({"risk": budget} if budget else {}))
    except Exception as exc:                  # recorded; the sweep goes on
        return rec | {"stage": "plan", "error": f"{type(exc).__name__}: {exc}"[:300]}
    if not plan.success:
        return rec | {"stage": "plan", "error": "no path"}
    kw = {"risk": budget, "allocation": case["allocation"], "risk_kind": case["risk_kind"]} if budget else {}
    t = time.perf_counter()
    try:
        r = bn.smooth(sc, plan.path, K=case["K"], method=case["method"], alpha=case["alpha"],
                      time_limit=case["time_limit"], **kw)
    except Exception as exc:                  # a refusal (no warm start, an option) or a bug: recorded
        return rec | {"stage": "smooth", "error": f"{type(exc).__name__}: {exc}"[:300]}
    wall = time.perf_counter() - t
    if budget:
        rep = bn.verify(sc, r.path, levels=r.risk.levels, budget=budget)
    else:
        rep = bn.verify(sc, r.path)
    return rec | {"status": r.status, "safe": bool(r.safe), "verified": bool(rep.safe), "nit": int(r.nit),
                  "wall_s": round(wall, 3), "cost": r.cost, "initial_cost": r.initial_cost, "by": r.method,
                  "bound": None if r.risk is None else float(r.risk.bound)}


def summarise(records: list[dict]) -> dict:
    counts = collections.Counter()
    flagged = []
    for r in records:
        if "error" in r:
            counts[f"{r['method']}: {r['error'].split(':')[0]}"] += 1
            if not r["error"].startswith(("InfeasibleStartError", "no path")):
                flagged.append(r)
            continue
        counts[f"{r['method']}: {r['status']}, verified={r['verified']}"] += 1
        over = r["bound"] is not None and r["bound"] > r["budget"] * (1 + 1e-9)
        if not r["verified"] or over or r["status"] != "converged" or not r["cost"] < r["initial_cost"]:
            flagged.append({k: r.get(k) for k in ("family", "map", "method", "alpha", "allocation", "risk_kind",
                                                   "status", "verified", "cost", "initial_cost", "wall_s")})
    solved = [r for r in records if "error" not in r]
    return {"cases": len(records), "solved": len(solved), "verified": sum(r["verified"] for r in solved),
            "counts": dict(sorted(counts.items())), "flagged": flagged}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--families", nargs="+", default=["random-polygons:40-50"], help="family:first-end (end excluded)")
    ap.add_argument("--methods", nargs="+", default=["auto", "ccp", "fatrop", "sqp"])
    ap.add_argument("--K", type=int, default=20)
    ap.add_argument("--alphas", type=float, nargs="+", default=[0.1])
    ap.add_argument("--budget", type=float, default=None, help="a risk budget Delta (both allocations, both kinds)")
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=RESULTS / "stress.json")
    args = ap.parse_args(argv)
    budgets = ([{"budget": args.budget, "allocation": a, "risk_kind": k} for k in ("steps", "continuous")
                for a in ("optimal", "uniform")] if args.budget else [{"budget": None}])
    cases = [{"family": fam, "map": m, "K": args.K, "method": meth, "alpha": alpha, "time_limit": args.time_limit,
              **b} for spec in args.families for fam, m in _maps(spec) for meth in args.methods
             for alpha in args.alphas for b in budgets]
    run_and_record(run_case, cases, summarise, args, args.out, args.workers)


if __name__ == "__main__":
    main()
