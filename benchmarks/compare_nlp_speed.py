"""Two records of ``bench_nlp_speed.py`` case by case (the same warm starts:
family, seed, K, alpha and method match).

Per (method, K): median iterations and wall seconds of each record, the
median per-case wall ratio, the cost ratio new / old (min, median, max) and
how many cases end beyond 0.1 % above or below, and converged & verified
counts. Prints a markdown table; ``--out`` also writes it as JSON.

    python benchmarks/compare_nlp_speed.py OLD.json NEW.json [--out FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _key(c: dict) -> tuple:
    return c["method"], c["K"], c["family"], c["seed"], c["alpha"]


def compare(old: dict, new: dict) -> list[dict]:
    """Rows per (method, K) over the cases both records hold."""
    before = {_key(c): c for c in old["cases"]}
    groups: dict[tuple, list[tuple[dict, dict]]] = {}
    for c in new["cases"]:
        if _key(c) in before:
            groups.setdefault((c["method"], c["K"]), []).append((before[_key(c)], c))
    rows = []
    for (method, K), pairs in sorted(groups.items()):
        a, b = zip(*pairs)
        cost = np.array([y["cost"] / x["cost"] for x, y in pairs])
        wall = np.array([y["wall_s"] / x["wall_s"] for x, y in pairs])
        ok = [sum(c["status"] == "converged" and c["verified"] for c in side) for side in (a, b)]
        rows.append({"method": method, "K": K, "cases": len(pairs),
                     "median_iterations": [float(np.median([c["iterations"] for c in side])) for side in (a, b)],
                     "median_wall_s": [float(np.median([c["wall_s"] for c in side])) for side in (a, b)],
                     "wall_ratio_median": float(np.median(wall)),
                     "cost_ratio": [float(cost.min()), float(np.median(cost)), float(cost.max())],
                     "above_0_1_percent": int((cost > 1.001).sum()), "below_0_1_percent": int((cost < 0.999).sum()),
                     "converged_verified": ok})
    return rows


def markdown(rows: list[dict]) -> str:
    out = ["| method | K | cases | median its | median wall s | wall ratio | cost new/old: min, median, max "
           "| beyond 0.1 %: above, below | converged & verified |", "|---" * 9 + "|"]
    for r in rows:
        its, wall, cr = r["median_iterations"], r["median_wall_s"], r["cost_ratio"]
        out.append(f"| {r['method']} | {r['K']} | {r['cases']} | {its[0]:g} -> {its[1]:g} | "
                   f"{wall[0]:.3f} -> {wall[1]:.3f} | {r['wall_ratio_median']:.3f} | "
                   f"{cr[0]:.5f}, {cr[1]:.6f}, {cr[2]:.5f} | {r['above_0_1_percent']}, {r['below_0_1_percent']} | "
                   f"{r['converged_verified'][0]} -> {r['converged_verified'][1]} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    rows = compare(json.loads(args.old.read_text()), json.loads(args.new.read_text()))
    print(markdown(rows))
    if args.out:
        args.out.write_text(json.dumps({"old": str(args.old), "new": str(args.new), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
