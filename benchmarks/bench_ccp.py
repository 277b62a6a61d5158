"""The sequential-convex route (issue 19): conditioning, cascade, speed, and
whether a CCP pass after IPOPT (``auto``'s ``ccp_polish``) pays.

Cases: paper-multi with planner seeds 0..S-1 and S random-polygons maps
(planner seed 0); alpha 0.1 and 1.0; K = 20 (S cases per scenario kind) and
K = 40 (S40); IG-RRT* with N = 500 nodes and per-step noise. Every method
smooths the same warm start (a WarmStart at K). Per case:

* ``ccp`` (max_iter 100, tol 1e-5): status, iterations, wall and solver time,
  which cascade entry answered each step, how many steps were extrapolated;
* ``ccp-plain``: the same without the extrapolated linearisation point
  (``accelerate=False``);
* ``ipopt``, ``auto`` and ``auto`` with ``ccp_polish=10``: status, cost, wall;
* with ``--check``: a second CCP run whose hook solves every step's problem
  (parameters set) with the library's Clarabel settings, Clarabel's defaults
  and (at steps 1 and 20) SCS at eps 1e-7, recording each objective: the
  conditioning evidence (every subproblem, same optimum).

Writes benchmarks/results/ccp.json (machine, load, per-case records, tables)
and prints the Markdown tables.

    python benchmarks/bench_ccp.py [--seeds 10] [--seeds40 5] [--workers 2] [--check] [--methods M,...]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

from _record import run_and_record

OUT = Path(__file__).resolve().parent / "results" / "ccp.json"
METHODS = {"ccp": ("ccp", {"max_iter": 100, "tol": 1e-5}),
           "ccp-plain": ("ccp", {"max_iter": 100, "tol": 1e-5, "accelerate": False}),
           "ipopt": ("ipopt", {}), "auto": ("auto", {"ccp_polish": 0}), "auto+polish": ("auto", {"ccp_polish": 10})}
LIBRARY = {"equilibrate_enable": False, "chordal_decomposition_enable": False, "presolve_enable": False}
SCS_CHECK = {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iters": 200_000}


def _scenario(kind: str, seed: int):
    import belief_nlp as bn
    from belief_nlp.families import generate

    return (bn.load_scenario("paper-multi"), seed) if kind == "paper-multi" else (generate("random-polygons", seed), 0)


def _solve_value(prob, solver, opts):
    import cvxpy as cp

    t = time.perf_counter()
    try:
        prob.solve(solver=solver, warm_start=False, **opts)      # a new solver object: exactly these settings
        return {"status": str(prob.status), "value": float(prob.value) if prob.value is not None else None,
                "time": time.perf_counter() - t}
    except cp.error.SolverError as exc:
        return {"status": f"error: {str(exc)[:60]}", "value": None, "time": time.perf_counter() - t}


def run_case(case: dict) -> dict:
    warnings.simplefilter("ignore")
    import belief_nlp as bn

    sc, pseed = _scenario(case["kind"], case["seed"])
    out = dict(case, load=os.getloadavg()[0])
    planned = bn.plan(sc, n_nodes=500, seed=pseed, noise="per_step")
    if planned.path is None:
        return dict(out, error="no plan")
    try:
        ws = bn.warm_start(sc, planned.path, K=case["K"])
    except bn.BeliefNLPError as exc:
        return dict(out, error=f"warm start: {exc}")
    a = case["alpha"]
    for method in ("ccp", "ipopt"):            # builds (CVXPY compile, NLP) are cached: time none of them
        bn.smooth(sc, ws, method=method, alpha=a, max_iter=1)
    runs = {}
    for name, (method, opts) in METHODS.items():
        if name not in case.get("methods", METHODS):
            continue
        t = time.perf_counter()
        r = bn.smooth(sc, ws, method=method, alpha=a, **opts)
        wall = time.perf_counter() - t
        rec = {"status": r.status, "nit": r.nit, "cost": r.cost, "initial_cost": r.initial_cost, "wall": wall,
               "safe": bool(r.safe), "method": r.method}
        if method == "ccp":
            rec["extrapolated"] = sum("extrapolated" in str(s["solver"]) for s in r.stats.get("steps", []))
            steps = r.stats.get("steps", [])
            rec["solve_time"] = r.stats.get("solve_time")
            rec["answered_by"] = [s["solver"] for s in steps]
            rec["attempts"] = sum(len(s["attempts"]) for s in steps)
        runs[name] = rec
    out["runs"] = runs
    if case.get("check"):
        checks = []

        def hook(step, it):
            row = {"iteration": it, "library": _solve_value(step.problem, "CLARABEL", LIBRARY),
                   "defaults": _solve_value(step.problem, "CLARABEL", {})}
            if it in (1, 20):
                row["scs"] = _solve_value(step.problem, "SCS", SCS_CHECK)
            checks.append(row)

        bn.smooth(sc, ws, method="ccp", alpha=a, max_iter=100, tol=1e-5, hook=hook)
        out["checks"] = checks
    return out


def _rel(a, b):
    return abs(a - b) / max(abs(b), 1e-12) if a is not None and b is not None else np.inf


def summarise(records: list[dict]) -> dict:
    ok = [r for r in records if "runs" in r]
    table = {}
    for K in sorted({r["K"] for r in ok}):
        rows = [r for r in ok if r["K"] == K]
        best = {id(r): min(v["cost"] for v in r["runs"].values() if v["safe"]) for r in rows}
        present = [m for m in METHODS if all(m in r["runs"] for r in rows)]
        for m in present:
            v = [r["runs"][m] for r in rows]
            table[f"K{K}/{m}"] = {
                "cases": len(v),
                "converged": sum(x["status"] == "converged" for x in v),
                "verified": sum(x["safe"] for x in v),
                "median_wall": float(np.median([x["wall"] for x in v])),
                "median_nit": float(np.median([x["nit"] for x in v])),
                "cost_over_best_median": float(np.median([x["cost"] / best[id(r)] for x, r in zip(v, rows)])),
                "cost_over_best_max": float(np.max([x["cost"] / best[id(r)] for x, r in zip(v, rows)])),
                "statuses": sorted({x["status"] for x in v}),
            }
        if {"ccp", "ipopt", "ccp-plain"} <= set(present):
            ratio = [r["runs"]["ccp"]["wall"] / r["runs"]["ipopt"]["wall"] for r in rows]
            table[f"K{K}/ccp_over_ipopt_wall_median"] = float(np.median(ratio))
            table[f"K{K}/ccp_over_plain_wall_median"] = float(np.median(
                [r["runs"]["ccp"]["wall"] / r["runs"]["ccp-plain"]["wall"] for r in rows]))
            table[f"K{K}/ccp_steps_extrapolated"] = int(sum(r["runs"]["ccp"]["extrapolated"] for r in rows))
            answered = [s for r in rows for s in r["runs"]["ccp"]["answered_by"]]
            table[f"K{K}/ccp_steps_answered_by"] = {k: answered.count(k) for k in sorted(set(map(str, answered)))}
        if {"auto", "auto+polish"} <= set(present):
            pol = [(r["runs"]["auto+polish"]["cost"], r["runs"]["auto"]["cost"], r["runs"]["auto+polish"]["wall"],
                    r["runs"]["auto"]["wall"]) for r in rows]
            table[f"K{K}/polish"] = {
                "lower_by_more_than_0.1%": sum(p < c * (1 - 1e-3) for p, c, _, _ in pol),
                "max_decrease_%": float(max(100 * (c - p) / c for p, c, _, _ in pol)),
                "median_cost_ratio": float(np.median([p / c for p, c, _, _ in pol])),
                "median_wall_ratio": float(np.median([pw / w for _, _, pw, w in pol])),
            }
    checks = [c for r in ok for c in r.get("checks", [])]
    if checks:
        lib_ok = [c for c in checks if c["library"]["value"] is not None]
        table["checks"] = {
            "subproblems": len(checks),
            "library_solved": sum(c["library"]["status"] in ("optimal", "optimal_inaccurate") for c in checks),
            "library_optimal": sum(c["library"]["status"] == "optimal" for c in checks),
            "defaults_solved": sum(c["defaults"]["status"] in ("optimal", "optimal_inaccurate") for c in checks),
            "defaults_optimal": sum(c["defaults"]["status"] == "optimal" for c in checks),
            "defaults_vs_library_max_rel": float(max(_rel(c["defaults"]["value"], c["library"]["value"])
                                                     for c in lib_ok)),
            "defaults_within_1e-6": sum(_rel(c["defaults"]["value"], c["library"]["value"]) <= 1e-6 for c in lib_ok),
            "scs_checked": sum("scs" in c for c in checks),
            "scs_within_1e-5": sum(_rel(c["scs"]["value"], c["library"]["value"]) <= 1e-5 for c in lib_ok if "scs" in c),
            "scs_vs_library_max_rel": float(max([_rel(c["scs"]["value"], c["library"]["value"])
                                                 for c in lib_ok if "scs" in c] or [0.0])),
        }
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seeds40", type=int, default=5)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--check", action="store_true", help="also solve every step with other solvers/settings")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--methods", default=",".join(METHODS),
                    help=f"comma-separated subset of {', '.join(METHODS)} (e.g. auto,auto+polish)")
    a = ap.parse_args()
    methods = a.methods.split(",")
    bad = sorted(set(methods) - set(METHODS))
    if bad:
        ap.error(f"--methods: unknown {bad}; choose from {list(METHODS)}")
    cases = [dict(kind=kind, seed=s, alpha=al, K=K, check=a.check, methods=methods)
             for K, n in ((20, a.seeds), (40, a.seeds40)) for kind in ("paper-multi", "random-polygons")
             for s in range(n) for al in (0.1, 1.0)]
    run_and_record(run_case, cases, summarise, a, a.out, a.workers)


if __name__ == "__main__":
    main()
