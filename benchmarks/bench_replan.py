"""Re-planning from a new start belief: what a call costs when the scenario's
build is reused, against a call that builds everything (issue 21, item 5).

The start belief (x0, P0) is a parameter of every form (the NLP's ``p``, the
CCP step's parameters), so a re-plan from a new belief on the same scenario
and K reuses the NLP graph, IPOPT's derivatives and solver, and the CCP
step's conic data. Before, the start was a constant of each form and part of
the cache key, so every new start built all of them: the "rebuild" rows
(caches cleared before the call) are what a new start cost then.

Protocol: paper-multi, ``--starts`` start beliefs (x0 moved up to 3 cm from
the paper's, P0 = 1e-9 .. 1e-5 I), each with its own IG-RRT* plan (N = 500,
per-step noise, seed = start index) and warm start at K; ``--method``
(default auto), alpha 1. One process. Per start: caches cleared, the call
timed ("rebuild"); the previous start solved again (the cache now holds the
scenario's build, last used with another start); the call timed again
("reuse"). Both answers must be equal (cost to 1e-8) and verified.
Then ``bn.replan`` from the answer at the paper's own start (the previous
plan of a control loop whose belief moved): "replan" rows, warm started from
that answer instead of a new plan, its first IPOPT stage resumed from the
answer's variables and multipliers (``SmoothResult.resume``); "replan_path"
rows the same from the re-anchored path alone (``resume`` dropped). Their
iterations, CPU and cost against the "reuse" call's; a start whose
re-anchored first step is not clear is recorded as infeasible.

    python benchmarks/bench_replan.py [--K 20 40] [--starts 8] [--method auto] [--ccp-polish N] [--out FILE]

``--ccp-polish`` sets auto's ``ccp_polish`` for the two re-plan calls only.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from _record import write_record
from belief_nlp.methods.nlp_build import clear_cache
from belief_nlp.model.cache import MEMORY

HERE = Path(__file__).resolve().parent / "results"


def _starts(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """n (x0, P0): x0 on rings of 1-3 cm around the paper's start, P0 = 1e-9 .. 1e-5 I."""
    base = bn.load_scenario("paper-multi")
    out = []
    for i in range(n):
        r, a = 0.01 * (1 + i % 3), 2 * np.pi * i / max(n, 1)
        out.append((base.x0 + r * np.array([np.cos(a), np.sin(a)]), 10.0 ** (-9 + i % 5) * np.eye(2)))
    return out


def _case(x0, P0, seed: int, K: int):
    sc = bn.load_scenario("paper-multi").with_options(x0=x0, P0=P0)
    plan = bn.plan(sc, n_nodes=500, seed=seed, noise="per_step")
    if not plan.success:
        return None
    try:
        return sc, bn.warm_start(sc, plan.path, K=K)
    except bn.errors.BeliefNLPError:
        return None


def _timed(sc, ws, method: str, previous=None, **kw) -> dict:
    load = os.getloadavg()[0]
    t, c = time.perf_counter(), time.process_time()
    try:
        res = bn.replan(sc, previous, method=method, alpha=1.0, **kw) if previous is not None else \
            bn.smooth(sc, ws, method=method, alpha=1.0, **kw)
    except bn.InfeasibleStartError as exc:
        return {"status": "infeasible_start", "error": str(exc)[:200], "cpu_s": time.process_time() - c}
    return {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "status": res.status,
            "iterations": int(res.nit), "cost": float(res.cost), "verified": bool(bn.verify(sc, res.path).safe),
            "build": res.stats.get("build") or res.stats.get("ipopt", {}).get("build"), "load": load,
            "resumed": res.stats.get("resumed") or res.stats.get("ipopt", {}).get("resumed")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--K", type=int, nargs="+", default=[20, 40])
    ap.add_argument("--starts", type=int, default=8)
    ap.add_argument("--method", default="auto")
    ap.add_argument("--ccp-polish", type=int, default=None, help="auto's ccp_polish for the re-plans (default: auto's)")
    ap.add_argument("--out", type=Path, default=HERE / "replan.json")
    args = ap.parse_args()
    kw = {} if args.ccp_polish is None else {"ccp_polish": args.ccp_polish}
    t0, load0 = time.time(), os.getloadavg()
    records, table = [], {}
    for K in args.K:
        cases = [(i, c) for i, (x0, P0) in enumerate(_starts(args.starts)) if (c := _case(x0, P0, i, K))]
        base = bn.load_scenario("paper-multi")       # the previous plan (also the imports, numba, first calls)
        previous = bn.smooth(base, bn.warm_start(base, bn.plan(base, n_nodes=500, seed=0, noise="per_step").path,
                                                 K=K), method=args.method, alpha=1.0)
        rows = []
        for n, (i, (sc, ws)) in enumerate(cases):
            clear_cache()
            MEMORY.clear()
            rebuild = _timed(sc, ws, args.method)
            _timed(*cases[n - 1][1], args.method)                # the build now last used with another start
            reuse = _timed(sc, ws, args.method)
            again = _timed(sc, ws, args.method, previous, **kw)
            path_only = _timed(sc, ws, args.method, dataclasses.replace(previous, resume=None), **kw)
            rows.append({"K": K, "start": i, "x0": sc.x0.tolist(), "P0": float(sc.P0[0, 0]),
                         "rebuild": rebuild, "reuse": reuse, "replan": again, "replan_path": path_only})
            print(f"K={K} start {i}: rebuild {rebuild['cpu_s']:.2f} s, reuse {reuse['cpu_s']:.2f} s CPU, "
                  f"costs {rebuild['cost']:.6f} / {reuse['cost']:.6f}; replan {again['status']} "
                  f"{again['cpu_s']:.2f} s {again.get('iterations')} its {again.get('cost', float('nan')):.6f} "
                  f"(path only {path_only['cpu_s']:.2f} s {path_only.get('iterations')} its)",
                  flush=True)
        records += rows
        cpu_b = np.array([r["rebuild"]["cpu_s"] for r in rows])
        cpu_r = np.array([r["reuse"]["cpu_s"] for r in rows])
        rel = np.array([abs(r["reuse"]["cost"] - r["rebuild"]["cost"]) / abs(r["rebuild"]["cost"]) for r in rows])
        table[f"K={K}"] = {"cases": len(rows), "median_cpu_rebuild_s": float(np.median(cpu_b)),
                           "median_cpu_reuse_s": float(np.median(cpu_r)),
                           "median_saved_s": float(np.median(cpu_b - cpu_r)),
                           "median_ratio_reuse_to_rebuild": float(np.median(cpu_r / cpu_b)),
                           "max_cost_rel_difference": float(rel.max()),
                           "verified": int(sum(r["rebuild"]["verified"] and r["reuse"]["verified"] for r in rows)),
                           "median_iterations": float(np.median([r["reuse"]["iterations"] for r in rows]))}
        ok = [r for r in rows if r["replan"]["status"] != "infeasible_start"]
        if ok:
            table[f"K={K}"].update({
                "replan_cases": len(ok), "replan_infeasible_start": len(rows) - len(ok),
                "replan_verified": int(sum(r["replan"]["verified"] for r in ok)),
                "median_cpu_replan_s": float(np.median([r["replan"]["cpu_s"] for r in ok])),
                "median_iterations_replan": float(np.median([r["replan"]["iterations"] for r in ok])),
                "median_cpu_replan_path_s": float(np.median([r["replan_path"]["cpu_s"] for r in ok])),
                "median_iterations_replan_path": float(np.median([r["replan_path"]["iterations"] for r in ok])),
                "resumed": [r["replan"].get("resumed") for r in ok],
                "median_iterations_reuse_same_cases": float(np.median([r["reuse"]["iterations"] for r in ok])),
                "median_cpu_reuse_same_cases_s": float(np.median([r["reuse"]["cpu_s"] for r in ok])),
                "replan_cost_over_reuse_cost": [float(f(np.array([r["replan"]["cost"] / r["reuse"]["cost"]
                                                                  for r in ok]))) for f in (np.min, np.median,
                                                                                            np.max)]})
    write_record(args.out, args, table, records, t0, load0)


if __name__ == "__main__":
    main()
