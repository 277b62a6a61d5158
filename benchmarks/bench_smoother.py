"""CCP smoother benchmark on paper-multi: the compiled CVXPY step.

For K in {20, 40} and alpha in {0.1, 1.0}:

* hand-made start (the route of tests/conftest.py, S_k = 1e4 I; the start of
  the previous records, so converged costs compare): the symbolic model's
  build time, the first compile of the CVXPY problem (canonicalisation
  included), its reload time from the disk cache, per-iteration wall time
  against Clarabel's own solve time, cost after 15 iterations, converged
  cost and iterations (tol 1e-4), and the relative difference to the
  converged cost of the previous record (``--previous``);
* IG-RRT* warm starts (N = 500, per-step noise, seeds 0..S-1; one step per
  edge when the K-step warm start is infeasible): converged cost,
  iterations, per-iteration ratio, end-to-end wall time.

Writes benchmarks/results/smoother.json and prints the tables.

    python benchmarks/bench_smoother.py [--quick] [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.methods.ccp import CHI2_MARGIN, compiled_step
from belief_nlp.model import BeliefModel
from belief_nlp.model.cache import MEMORY, DiskCache, problem_key

WAYPOINTS = np.array([(0.15, 0.50), (0.15, 0.80), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)])


def hand_path(sc, K: int) -> bn.BeliefPath:
    per = K // (len(WAYPOINTS) - 1)
    t = np.arange(1, per + 1)[:, None] / per
    x = np.vstack([WAYPOINTS[:1]] + [WAYPOINTS[i] + t * (WAYPOINTS[i + 1] - WAYPOINTS[i])
                                     for i in range(len(WAYPOINTS) - 1)])
    S = np.broadcast_to(1e4 * np.eye(2), (x.shape[0] - 1, 2, 2))
    return bn.BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)


def _iteration_stats(res) -> dict:
    its = [h for h in res.history[1:] if h.accepted]
    later = its[1:] if len(its) > 1 else its
    wall = np.array([h.wall_time for h in later])
    solve = np.array([h.solve_time for h in later])
    return {"per_iteration_wall_s": float(np.median(wall)), "per_iteration_clarabel_s": float(np.median(solve)),
            "wall_over_clarabel": float(np.median(wall / solve)),
            "first_iteration_wall_s": its[0].wall_time if its else float("nan")}


def compile_times(sc, K: int, alpha: float) -> dict:
    """Model build, first compile (CVXPY canonicalisation included) and disk reload."""
    import cvxpy as cp

    MEMORY.clear()
    t0 = time.perf_counter()
    model = BeliefModel(sc, K, alpha)
    _ = model.convex_form
    t1 = time.perf_counter()
    step, _, _ = compiled_step(model)
    t2 = time.perf_counter()
    step.problem.get_problem_data(cp.CLARABEL)
    t3 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        disk = DiskCache(tmp)
        key = problem_key(model.data, CHI2_MARGIN, "CLARABEL")
        disk.save(key, step)
        size = (Path(tmp) / (key + disk.suffix)).stat().st_size
        t4 = time.perf_counter()
        back = disk.load(key)
        t5 = time.perf_counter()
    assert back is not None
    return {"model_build_s": t1 - t0, "compile_s": t3 - t1, "cvxpy_canonicalise_s": t3 - t2,
            "disk_reload_s": t5 - t4, "disk_entry_bytes": size, "parameters": int(sum(step.sizes))}


def hand_row(K: int, alpha: float, previous: dict) -> dict:
    sc = bn.load_scenario("paper-multi")
    row = {"start": "hand", "K": K, "alpha": alpha, **compile_times(sc, K, alpha)}
    ws = bn.warm_start(sc, hand_path(sc, K))
    MEMORY.clear()
    t0 = time.perf_counter()
    res = bn.smooth(sc, ws, alpha=alpha, max_iter=100, tol=1e-4)
    row.update(total_wall_s=time.perf_counter() - t0, status=res.status, iterations=res.nit,
               initial_cost=res.initial_cost, cost_after_15=res.history[min(15, res.nit)].cost,
               final_cost=res.cost, safe=res.safe, **_iteration_stats(res))
    old = previous.get((K, alpha))
    row["previous_final_cost"] = old
    row["relative_to_previous"] = (res.cost - old) / old if old else None
    return row


def planner_rows(K: int, alpha: float, seeds: int) -> list[dict]:
    sc = bn.load_scenario("paper-multi")
    rows = []
    for seed in range(seeds):
        planned = bn.plan(sc, n_nodes=500, seed=seed, alpha=alpha, noise="per_step", max_radius=1.5)
        if not planned.success:
            rows.append({"start": "ig-rrt*", "K": K, "alpha": alpha, "seed": seed, "status": "no plan"})
            continue
        try:
            ws, k_used = bn.warm_start(sc, planned.path, K=max(K, planned.path.K)), K
        except bn.InfeasibleStartError:
            ws, k_used = bn.warm_start(sc, planned.path), planned.path.K
        t0 = time.perf_counter()
        res = bn.smooth(sc, ws, alpha=alpha, max_iter=100, tol=1e-4)
        rows.append({"start": "ig-rrt*", "K": K, "K_used": k_used, "alpha": alpha, "seed": seed,
                     "status": res.status, "iterations": res.nit, "initial_cost": res.initial_cost,
                     "final_cost": res.cost, "safe": res.safe, "total_wall_s": time.perf_counter() - t0,
                     **_iteration_stats(res)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K = 20 only, one seed")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "smoother.json")
    ap.add_argument("--previous", type=Path, default=Path(__file__).parent / "results" / "smoother.json",
                    help="earlier record whose converged costs the hand rows are compared with")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    previous = {}
    if args.previous.exists():
        for r in json.loads(args.previous.read_text()).get("rows", []):
            if r.get("start", "hand") == "hand":
                previous[(r["K"], r["alpha"])] = r.get("previous_final_cost") or r["final_cost"]
    Ks = (20,) if args.quick else (20, 40)
    seeds = 1 if args.quick else args.seeds
    rows = [hand_row(K, a, previous) for K in Ks for a in (0.1, 1.0)]
    rows += [r for K in Ks for a in (0.1, 1.0) for r in planner_rows(K, a, seeds)]
    record = {
        "benchmark": "ccp smoother (compiled CVXPY step), paper-multi",
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cpus": os.cpu_count(), "load_average": os.getloadavg()},
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2, default=float))
    print(f"{'K':>3} {'alpha':>5} {'model s':>7} {'compile s':>9} {'reload s':>8} {'it wall s':>9} "
          f"{'clarabel s':>10} {'ratio':>5} {'cost@15':>8} {'final':>8} {'its':>4} {'vs prev':>9} total s")
    for r in rows:
        if r["start"] != "hand":
            continue
        rel = r["relative_to_previous"]
        print(f"{r['K']:>3} {r['alpha']:>5} {r['model_build_s']:>7.3f} {r['compile_s']:>9.3f} "
              f"{r['disk_reload_s']:>8.3f} {r['per_iteration_wall_s']:>9.3f} {r['per_iteration_clarabel_s']:>10.3f} "
              f"{r['wall_over_clarabel']:>5.2f} {r['cost_after_15']:>8.4f} {r['final_cost']:>8.4f} "
              f"{r['iterations']:>4} {rel if rel is None else format(rel, '.1e'):>9} {r['total_wall_s']:.1f}")
    print(f"\n{'K':>3} {'alpha':>5} {'seed':>4} {'K used':>6} {'start':>8} {'final':>8} {'its':>4} {'ratio':>5} "
          f"{'total s':>7} status")
    for r in rows:
        if r["start"] == "hand" or "final_cost" not in r:
            continue
        print(f"{r['K']:>3} {r['alpha']:>5} {r['seed']:>4} {r['K_used']:>6} {r['initial_cost']:>8.4f} "
              f"{r['final_cost']:>8.4f} {r['iterations']:>4} {r['wall_over_clarabel']:>5.2f} "
              f"{r['total_wall_s']:>7.2f} {r['status']}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
