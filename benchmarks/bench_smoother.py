"""CCP smoother benchmark on paper-multi (issue: smoother performance).

For K in {20, 40} and alpha in {0.1, 1.0}, from a hand-made feasible path
(the route of tests/conftest.py, S_k = 1e4 I), records: first build time
(conic layout + first assembly), per-iteration wall time vs Clarabel's own
solve time, cost after 15 iterations, and iterations to a 1e-4 relative
tolerance. Writes benchmarks/results/smoother.json and prints a table.

    python benchmarks/bench_smoother.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn

WAYPOINTS = np.array([(0.15, 0.50), (0.15, 0.80), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)])


def hand_path(sc, K: int) -> bn.BeliefPath:
    per = K // (len(WAYPOINTS) - 1)
    t = np.arange(1, per + 1)[:, None] / per
    x = np.vstack([WAYPOINTS[:1]] + [WAYPOINTS[i] + t * (WAYPOINTS[i + 1] - WAYPOINTS[i])
                                     for i in range(len(WAYPOINTS) - 1)])
    S = np.broadcast_to(1e4 * np.eye(2), (x.shape[0] - 1, 2, 2))
    return bn.BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)


def run(K: int, alpha: float, max_iter: int) -> dict:
    sc = bn.load_scenario("paper-multi")
    ws = bn.warm_start(sc, hand_path(sc, K))
    t0 = time.perf_counter()
    res = bn.smooth(sc, ws, alpha=alpha, max_iter=max_iter, tol=1e-4)
    wall = time.perf_counter() - t0
    its = [h for h in res.history[1:] if h.accepted]
    later = its[1:] if len(its) > 1 else its
    cost15 = res.history[min(15, len(res.history) - 1)].cost
    per_wall = float(np.mean([h.wall_time for h in later]))
    per_solve = float(np.mean([h.solve_time for h in later]))
    return {
        "K": K, "alpha": alpha, "status": res.status, "iterations": res.nit,
        "initial_cost": res.initial_cost, "cost_after_15": cost15, "final_cost": res.cost,
        "first_build_s": res.timings["setup"] + (its[0].build_time if its else 0.0),
        "first_iteration_wall_s": its[0].wall_time if its else float("nan"),
        "per_iteration_wall_s": per_wall, "per_iteration_clarabel_s": per_solve,
        "wall_over_clarabel": per_wall / per_solve if per_solve else float("nan"),
        "per_iteration_build_s": float(np.mean([h.build_time for h in later])),
        "total_wall_s": wall, "safe": res.safe,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K = 20 only")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "smoother.json")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    Ks = (20,) if args.quick else (20, 40)
    rows = [run(K, a, 80) for K in Ks for a in (0.1, 1.0)]
    record = {
        "benchmark": "ccp smoother, paper-multi, hand-made start path",
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cpus": os.cpu_count(), "processor": platform.processor()},
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2))
    hdr = (f"{'K':>3} {'alpha':>5} {'build s':>8} {'it wall s':>9} {'clarabel s':>10} {'ratio':>5} "
           f"{'cost@0':>8} {'cost@15':>8} {'final':>8} {'its(1e-4)':>9} status")
    print(hdr)
    for r in rows:
        print(f"{r['K']:>3} {r['alpha']:>5} {r['first_build_s']:>8.3f} {r['per_iteration_wall_s']:>9.3f} "
              f"{r['per_iteration_clarabel_s']:>10.3f} {r['wall_over_clarabel']:>5.2f} {r['initial_cost']:>8.4f} "
              f"{r['cost_after_15']:>8.4f} {r['final_cost']:>8.4f} {r['iterations']:>9} {r['status']}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
