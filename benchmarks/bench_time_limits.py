"""Time-limit overshoot of every registered method (issue: hardening).

paper-multi, the hand-made 20-step start, alpha = 1; each method is warmed
up once (compiled step / NLP in the memory cache), then run with
time_limit in {0.05, 0.3, 1, 2} s. Records wall time, overshoot and status to
benchmarks/results/time_limits.json and prints the table.

    python benchmarks/bench_time_limits.py
"""

from __future__ import annotations

import json
import logging
import os
import platform
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn

WAYPOINTS = np.array([(0.15, 0.50), (0.15, 0.80), (0.45, 0.80), (0.75, 0.70), (0.82, 0.33), (0.65, 0.05)])


def hand_path(sc, per: int = 4) -> bn.BeliefPath:
    t = np.arange(1, per + 1)[:, None] / per
    x = np.vstack([WAYPOINTS[:1]] + [WAYPOINTS[i] + t * (WAYPOINTS[i + 1] - WAYPOINTS[i]) for i in range(5)])
    return bn.BeliefPath.from_sensing(x, sc.P0, np.broadcast_to(1e4 * np.eye(2), (x.shape[0] - 1, 2, 2)), W=sc.W)


def main() -> None:
    logging.disable(logging.WARNING)
    sc = bn.load_scenario("paper-multi")
    path = hand_path(sc)
    rows = []
    for method in bn.available_methods():
        bn.smooth(sc, path, method=method, alpha=1.0, max_iter=2)           # warm the caches
        for limit in (0.05, 0.3, 1.0, 2.0):
            t0 = time.perf_counter()
            res = bn.smooth(sc, path, method=method, alpha=1.0, time_limit=limit, max_iter=10**5)
            wall = time.perf_counter() - t0
            rows.append({"method": method, "time_limit_s": limit, "wall_s": wall, "overshoot_s": wall - limit,
                         "overshoot_rel": (wall - limit) / limit, "status": res.status, "iterations": res.nit,
                         "safe": res.safe})
    out = Path(__file__).parent / "results" / "time_limits.json"
    out.write_text(json.dumps({"benchmark": "time-limit overshoot, paper-multi K = 20, alpha 1",
                               "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                           "load_average": os.getloadavg()}, "rows": rows}, indent=2))
    print(f"{'method':>8} {'limit s':>7} {'wall s':>7} {'over s':>7} {'over %':>6} {'its':>5} status")
    for r in rows:
        print(f"{r['method']:>8} {r['time_limit_s']:>7.2f} {r['wall_s']:>7.3f} {r['overshoot_s']:>7.3f} "
              f"{100 * r['overshoot_rel']:>6.0f} {r['iterations']:>5} {r['status']}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
