"""A receding-horizon loop: re-plan after every executed step (issue 21).

After a step the horizon is one shorter. Before session 14 each such
re-plan built the shorter horizon's NLP, derivatives and solver and started
from the re-anchored path ("path" rows: ``bn.replan`` with the previous
answer's resume state dropped, the caches cleared before each: a loop of
more horizons than the memory cache holds, 8 graphs, builds every one).
Now the previous answer's graph is solved
with the executed steps frozen at the new start belief, resumed from its
variables and multipliers ("frozen" rows: ``bn.replan`` as is); for
``fatrop`` and ``sqp``, which take no initial multipliers, solved there from
the re-anchored path (session 29).

Protocol: paper-multi; per seed an IG-RRT* plan (N = 500, per-step noise),
the warm start at K and ``--method``'s answer (alpha 1). Then ``--steps``
times: the robot's belief is the plan's step-1 belief with the mean moved
uniformly up to 0.5 mm per axis and the covariance scaled by a factor in
[0.5, 1] (a measurement that went as planned or better); both loops see the
same beliefs. Per re-plan: CPU, wall, iterations, cost, status, whether
IPOPT resumed, what was built, and the independent verification. One
process, after the first answer (the imports and the K graph built).

``--compiled`` runs the frozen loop only, with the derivative functions of
the K graphs compiled (``bn.set_disk_cache(folder, compile=True)``): a
first process fills a fresh cache folder and starts the background builds,
which are waited for; the loop then loads the libraries (what an MPC
deployment that compiled once pays per step).

    python benchmarks/bench_receding.py [--K 20 40] [--seeds 4] [--steps 5] [--method ipopt] [--ccp-polish N]
                                        [--compiled] [--out FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from _record import cpu_seconds, wait_for_compiled, write_record
from belief_nlp.methods.nlp_build import clear_cache
from belief_nlp.model.cache import MEMORY

HERE = Path(__file__).resolve().parent / "results"


def _beliefs(seed: int, steps: int) -> list[tuple[np.ndarray, float]]:
    """Per step: the mean's offset (m) and the covariance's factor."""
    rng = np.random.default_rng(1000 + seed)
    return [(rng.uniform(-5e-4, 5e-4, 2), float(rng.uniform(0.5, 1.0))) for _ in range(steps)]


def _loop(sc0, first, beliefs, method: str, frozen: bool, kw: dict) -> list[dict]:
    prev, rows = first, []
    for step, (dx, f) in enumerate(beliefs):
        sc = sc0.with_options(x0=prev.path.x[1] + dx, P0=f * prev.path.P[1])
        last = prev if frozen else dataclasses.replace(prev, resume=None)
        if not frozen:
            clear_cache()
            MEMORY.clear()
        load = os.getloadavg()[0]
        t, c = time.perf_counter(), cpu_seconds()          # fatrop's forked solves included
        try:
            r = bn.replan(sc, last, advance=1, method=method, alpha=1.0, **kw)
        except bn.InfeasibleStartError as exc:
            rows.append({"step": step, "status": "infeasible_start", "error": str(exc)[:200]})
            break
        wall, cpu = time.perf_counter() - t, cpu_seconds() - c
        st = r.stats.get("ipopt", r.stats)
        rows.append({"step": step, "K": r.path.K, "wall_s": wall, "cpu_s": cpu, "iterations": int(r.nit),
                     "cost": float(r.cost), "initial_cost": float(r.initial_cost), "status": r.status,
                     "resumed": st.get("resumed"), "resumed_stage": st.get("resumed_stage"), "build": st.get("build"), "load": load,
                     "ccp_frozen": r.stats.get("ccp", r.stats).get("frozen"),
                     "verified": bool(bn.verify(sc, r.path).safe)})
        prev = r
    return rows


def _summary(rows: list[dict], fz: list[dict]) -> dict:
    """Medians of the frozen re-plans, and against the building ones where they ran."""
    out = {
        "replans": len(fz), "seeds": len(rows),
        "median_cpu_frozen_s": float(np.median([a["cpu_s"] for a in fz])),
        "max_cpu_frozen_s": float(np.max([a["cpu_s"] for a in fz])),
        "median_wall_frozen_s": float(np.median([a["wall_s"] for a in fz])),
        "median_iterations_frozen": float(np.median([a["iterations"] for a in fz])),
        "verified_frozen": int(sum(a["verified"] for a in fz)),
        "resumed_yes": int(sum(a["resumed"] == "yes" for a in fz)),
        "on_graph": int(sum(a["resumed"] == "graph" for a in fz)),     # no multipliers (fatrop, Uno): graph only
        "resumed_polish": int(sum(a.get("resumed_stage") == "polish" for a in fz)),
        "ccp_polish_frozen": int(sum(bool(a.get("ccp_frozen")) for a in fz)),
        "statuses_frozen": {s: int(sum(a["status"] == s for a in fz)) for s in sorted({a["status"] for a in fz})},
        "infeasible_starts": int(sum(r["frozen"][-1]["status"] == "infeasible_start" for r in rows if r["frozen"])),
    }
    pairs = [(a, b) for r in rows for a, b in zip(r["frozen"], r["path"]) if "cost" in a and "cost" in b]
    if pairs:
        pa = [b for _, b in pairs]
        rel = np.array([(a["cost"] - b["cost"]) / b["cost"] for a, b in pairs])
        out.update({
            "median_cpu_path_s": float(np.median([b["cpu_s"] for b in pa])),
            "median_iterations_path": float(np.median([b["iterations"] for b in pa])),
            "cost_frozen_over_path_minus_1": [float(rel.min()), float(np.median(rel)), float(rel.max())],
            "verified": [int(sum(a["verified"] for a, _ in pairs)), int(sum(b["verified"] for b in pa))],
            "statuses_path": {s: int(sum(b["status"] == s for b in pa)) for s in sorted({b["status"] for b in pa})},
        })
    return out


def _compiled_cache(Ks: list[int], method: str) -> Path:
    """A cache folder holding the compiled derivatives of paper-multi's graph
    at each K (one graph per K: the start belief and alpha are parameters),
    filled by a separate process; waits for the background builds."""
    folder = Path(tempfile.mkdtemp(prefix="bench_receding_compiled_"))
    fill = ("import belief_nlp as bn; bn.set_disk_cache({f!r}, compile=True); sc = bn.load_scenario('paper-multi'); "
            "p = bn.plan(sc, n_nodes=500, seed=0, noise='per_step'); "
            "[bn.smooth(sc, bn.warm_start(sc, p.path, K=K), method={m!r}, alpha=1.0) for K in {Ks!r}]")
    subprocess.run([sys.executable, "-c", fill.format(f=str(folder), m=method, Ks=list(Ks))], check=True)
    wait_for_compiled(folder, len(Ks))
    return folder


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--K", type=int, nargs="+", default=[20, 40])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--method", default="ipopt")
    ap.add_argument("--ccp-polish", type=int, default=None, help="auto's ccp_polish (default: auto's)")
    ap.add_argument("--compiled", action="store_true",
                    help="the frozen loop only, on compiled derivative functions (a fresh disk cache)")
    ap.add_argument("--out", type=Path, default=HERE / "receding.json")
    args = ap.parse_args()
    if args.compiled:
        bn.set_disk_cache(_compiled_cache(args.K, args.method), compile=True)
    modes = ("frozen",) if args.compiled else ("frozen", "path")
    kw = {} if args.ccp_polish is None else {"ccp_polish": args.ccp_polish}
    t0, load0 = time.time(), os.getloadavg()
    sc0 = bn.load_scenario("paper-multi")
    records, table = [], {}
    for K in args.K:
        rows = []
        for seed in range(args.seeds):
            plan = bn.plan(sc0, n_nodes=500, seed=seed, noise="per_step")
            if not plan.success:
                continue
            first = bn.smooth(sc0, bn.warm_start(sc0, plan.path, K=K), method=args.method, alpha=1.0, **kw)
            beliefs = _beliefs(seed, args.steps)
            loops = {mode: _loop(sc0, first, beliefs, args.method, mode == "frozen", kw) for mode in modes}
            loops.setdefault("path", [{} for _ in loops["frozen"]])
            rows.append({"K": K, "seed": seed, "first_cost": float(first.cost), "first_iterations": int(first.nit),
                         **loops})
            for a, b in zip(loops["frozen"], loops["path"]):
                print(f"K={K} seed {seed} step {a['step']}: frozen {a.get('cpu_s', float('nan')):.3f} s "
                      f"{a.get('iterations')} its {a.get('cost', float('nan')):.7f} {a.get('resumed')}/{a.get('resumed_stage')} | path "
                      f"{b.get('cpu_s', float('nan')):.3f} s {b.get('iterations')} its "
                      f"{b.get('cost', float('nan')):.7f}", flush=True)
        records += rows
        fz = [a for r in rows for a in r["frozen"] if "cost" in a]
        if fz:
            table[f"K={K}"] = _summary(rows, fz)
    write_record(args.out, args, table, records, t0, load0)


if __name__ == "__main__":
    main()
