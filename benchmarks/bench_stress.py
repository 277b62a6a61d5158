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

With ``--replan N`` each case is a receding loop instead: after the smooth,
up to N ``bn.replan(..., advance=1)`` calls, each from the executed step's
planned mean moved by ``--error`` standard deviations of its planned
posterior (random per axis, seeded by the map). A start whose ellipse then
touches a hazard (``ValidationError`` from ``with_options``) is recorded and
taken as planned instead; a start no sensing can clear
(``InfeasibleStartError``) ends the loop (docs/mpc.md). With ``--relax`` each
start comes from ``bn.relaxed_start`` instead: its first transition held to a
level it can meet. With ``--build`` every re-plan builds its shorter horizon
(the last answer's resume state dropped), the comparison for re-plans on
the last graph.
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
        if case.get("confidence") is not None:          # may refuse a start not clear at that level
            sc = sc.with_options(confidence=case["confidence"])
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


def run_loop(case: dict) -> dict:
    """A receding loop (module doc): how far it got, how it ended, every re-plan verified?"""
    import numpy as np

    import belief_nlp as bn
    from belief_nlp.families import generate

    rec = dict(case)
    sc = generate(case["family"], case["map"])
    plan = bn.plan(sc, n_nodes=500, seed=0, noise="per_step")
    if not plan.success:
        return rec | {"stage": "plan", "error": "no path"}
    cur = bn.smooth(sc, plan.path, K=case["K"], method=case["method"], alpha=case["alpha"],
                    time_limit=case["time_limit"])
    rng = np.random.default_rng(case["map"])
    steps, ended, not_clear, relaxed = [], "full", 0, 0
    for _ in range(case["replan"]):
        if cur.path.K < 3:
            break
        x1 = cur.path.x[1] + case["error"] * rng.normal(size=sc.dim) * np.sqrt(np.diag(cur.path.P[1]))
        try:
            if case.get("relax"):                        # the first transition at a level it can meet
                now = bn.relaxed_start(sc, x1, cur.path.P[1], previous=cur, advance=1)
                relaxed += now.start_confidence is not None
            else:
                now = sc.with_options(x0=x1, P0=cur.path.P[1])
        except bn.ValidationError:                       # the start ellipse touches a hazard
            not_clear += 1
            now = sc.with_options(x0=cur.path.x[1], P0=cur.path.P[1])
        t = time.perf_counter()
        try:
            # --build: drop the last answer's resume state, so every re-plan builds its horizon
            nxt = bn.replan(now, cur, advance=1, method=case["method"],
                            **({"resume": None} if case.get("build") else {}))
        except Exception as exc:                         # InfeasibleStartError ends a loop; anything else too
            ended = type(exc).__name__
            break
        st = nxt.stats.get("ipopt", nxt.stats)              # auto: its NLP stage's
        steps.append({"status": nxt.status, "verified": bool(bn.verify(now, nxt.path).safe),
                      "wall_s": round(time.perf_counter() - t, 4), "start_confidence": now.start_confidence,
                      # what the re-plan ran on: the NLP state's graph, the frozen conic step
                      "resumed": st.get("resumed"), "frozen": nxt.stats.get("ccp", nxt.stats).get("frozen")})
        cur = nxt
    return rec | {"replans": len(steps), "ended": ended, "start_not_clear": not_clear, "relaxed": relaxed,
                  "verified": all(s["verified"] for s in steps), "steps": steps}


def summarise_loops(records: list[dict]) -> dict:
    import statistics

    counts = collections.Counter(f"{r['method']}: {r.get('ended', r.get('error'))}" for r in records)
    walls = collections.defaultdict(list)
    for r in records:
        walls[r["method"]] += [s["wall_s"] for s in r.get("steps", [])]
    done = [r for r in records if "steps" in r]
    return {"loops": len(records), "replans": sum(r["replans"] for r in done),
            "replans_verified": sum(s["verified"] for r in done for s in r["steps"]),
            "replans_converged": sum(s["status"] == "converged" for r in done for s in r["steps"]),
            "start_not_clear": sum(r["start_not_clear"] for r in done),
            "relaxed_starts": sum(r.get("relaxed", 0) for r in done), "ended": dict(sorted(counts.items())),
            "median_replan_wall_s": {m: statistics.median(w) for m, w in walls.items() if w}}


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
    ap.add_argument("--confidences", type=float, nargs="+", default=[None],
                    help="the scenarios' confidence levels (default: each family's own)")
    ap.add_argument("--budget", type=float, default=None, help="a risk budget Delta (both allocations, both kinds)")
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--replan", type=int, default=0, help="receding loops of up to N re-plans instead")
    ap.add_argument("--error", type=float, default=0.3, help="estimation error per executed step, in std devs")
    ap.add_argument("--relax", action="store_true",
                    help="re-plan from bn.relaxed_start (transition 1 at a level it can meet) in the loops")
    ap.add_argument("--build", action="store_true",
                    help="in the loops, every re-plan builds its shorter horizon (no resume state)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=RESULTS / "stress.json")
    args = ap.parse_args(argv)
    budgets = ([{"budget": args.budget, "allocation": a, "risk_kind": k} for k in ("steps", "continuous")
                for a in ("optimal", "uniform")] if args.budget else [{"budget": None}])
    if args.replan:
        cases = [{"family": fam, "map": m, "K": args.K, "method": meth, "alpha": args.alphas[0],
                  "time_limit": args.time_limit, "replan": args.replan, "error": args.error, "relax": args.relax,
                  "build": args.build}
                 for spec in args.families for fam, m in _maps(spec) for meth in args.methods]
        run_and_record(run_loop, cases, summarise_loops, args, args.out, args.workers)
        return
    cases = [{"family": fam, "map": m, "K": args.K, "method": meth, "alpha": alpha, "time_limit": args.time_limit,
              "confidence": conf, **b} for spec in args.families for fam, m in _maps(spec) for meth in args.methods
             for alpha in args.alphas for conf in args.confidences for b in budgets]
    run_and_record(run_case, cases, summarise, args, args.out, args.workers)


if __name__ == "__main__":
    main()
