"""MPC step times of the belief-space closed loop on paper-multi, per tool.

Runs ``belief_nlp.export.closed_loop`` (horizon 10, 20 steps) with each
installed tool and writes benchmarks/results/mpc.json: median and max step
time (s), median and max IPOPT iterations, fallback steps, verified safety.
Targets (issue 11): Opti + IPOPT (expand=True) median <= 50 ms, do-mpc <= 100 ms.

    python benchmarks/bench_mpc.py [--tools opti dompc rockit] [--horizon 10] [--steps 20]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.errors import SolverError
from belief_nlp.export import closed_loop, reference_path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tools", nargs="+", default=["opti", "dompc", "rockit"])
    ap.add_argument("--horizon", type=int, default=10)
    ap.add_argument("--steps", type=int, default=20)
    a = ap.parse_args()
    sc = bn.load_scenario("paper-multi")
    ref = reference_path(sc, a.steps)
    rows = []
    for tool in a.tools:
        t0 = time.perf_counter()
        try:
            path = closed_loop(sc, tool, horizon=a.horizon, steps=a.steps, reference=ref)
        except (SolverError, ImportError, ModuleNotFoundError) as exc:
            rows.append({"tool": tool, "horizon": a.horizon, "error": str(exc)})
            print(f"{tool}: {exc}")
            continue
        st, it = np.asarray(path.meta["step_times"]), np.asarray(path.meta["iterations"])
        row = {"tool": tool, "horizon": a.horizon, "steps": a.steps, "median_step_s": float(np.median(st)),
               "max_step_s": float(st.max()), "median_iterations": float(np.median(it)),
               "max_iterations": int(it.max()), "fallback_steps": path.meta["fallback_steps"],
               "safe": bool(bn.verify(sc, path).safe),
               "reached_target": bool(sc.target.contains(path.x[-1])), "wall_s": time.perf_counter() - t0}
        rows.append(row)
        print(row)
    out = Path(__file__).parent / "results" / "mpc.json"
    out.write_text(json.dumps({"scenario": "paper-multi", "load_average": os.getloadavg(), "rows": rows},
                              indent=1))
    print("wrote", out)


if __name__ == "__main__":
    main()
