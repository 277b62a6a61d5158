"""End-to-end risk budget study (issue 20, item 4): optimal vs uniform allocation
vs the paper's fixed chi2, with Monte-Carlo checks of the certified bounds.

Grid: paper-multi and the random-polygons family (map = seed), seeds 0-9,
alpha in {0.1, 1.0}, Delta in {0.01, 0.05, 0.1, 0.25}. Per (scenario, seed,
alpha) one IG-RRT* plan (N = 500, per-step noise) is smoothed (default
method ``auto``, K = 20 from the same plan, no fallback to one step per
edge, so that every cost compared is at K = 20; a warm start that cannot be
built is an error row with the smoother's message; ``--replan`` starts the
budgeted runs from ``bn.plan(..., risk=Delta)`` instead, a plan per Delta):

* ``fixed``: the paper's chi2 (no budget); its certified step-time bound
  (``result.verification["risk_step_time"]``) is what that level buys;
* ``optimal`` and ``uniform``: ``bn.smooth(..., risk=Delta, allocation=...)``
  for every Delta.

Each path records its cost, wall time, status, the certified step-time and
continuous-time bounds recomputed by ``bn.verify(...).risk`` and the
Monte-Carlo rates (:func:`belief_nlp.study.simulate`, feedback control, 95 %
Clopper-Pearson) of being inside a hazard at a step time (against the
step-time bound) and at any sampled instant (against the continuous bound;
sampling ``--substeps`` points per transition sees fewer crossings than the
continuous motion, so that comparison can only err in the bound's favour).

Writes benchmarks/results/risk.json (the records, the machine and load
averages) and risk.md (the table): per Delta and alpha the median cost
ratios optimal/uniform and optimal/fixed over paths solved by both, the
median step-time bound the fixed chi2 certifies, the Monte-Carlo step-time
rate over the certified bound (median and max) and the paths whose 95 %
interval lies wholly above it (a refuted bound),
and the median wall-time ratio of the budgeted smoother to the fixed-level
one from the same plan, and the error rows (no plan, no warm start; fixed-level errors count at
every Delta). ``--quick`` (seed 0, Delta 0.05 and 0.25) writes
risk_quick.json / risk_quick.md instead.

    python benchmarks/bench_risk.py [--quick] [--seeds 0-9] [--runs 10000]
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
from tqdm import tqdm

import belief_nlp as bn
from belief_nlp.families import generate
from belief_nlp.study import clopper_pearson, simulate

DELTAS = (0.01, 0.05, 0.1, 0.25)
QUICK_DELTAS = (0.05, 0.25)
ALPHAS = (0.1, 1.0)
SCENARIOS = ("paper-multi", "random-polygons")
ALLOCATIONS = ("optimal", "uniform")
K = 20
N_NODES = 500


def parse_seeds(text: str) -> list[int]:
    """"0-9" -> 0..9, "0,3,7" -> [0, 3, 7]."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi) + 1)) if hi else [int(lo)]
    return out


def scenario_for(name: str, seed: int):
    """paper-multi itself, or map ``seed`` of a family."""
    return bn.load_scenario(name) if name == "paper-multi" else generate(name, seed)


def measure(sc, res, wall: float, runs: int, substeps: int, mc_seed: int) -> dict:
    """One smoothed path's record: cost, time, status, both certified bounds and the MC rates."""
    rep = bn.verify(sc, res)            # a budgeted result: at its own levels and budget
    rb = rep.risk
    mc = simulate(sc, res.path, runs=runs, substeps=substeps, seed=mc_seed)
    step_lo, step_hi = clopper_pearson(mc.step_hazard_runs, mc.runs)
    cont_lo, cont_hi = clopper_pearson(mc.hazard_runs, mc.runs)
    risk = getattr(res, "risk", None)
    return {
        "status": res.status, "success": bool(res.success), "method_used": res.method, "K_used": res.path.K,
        "cost": float(res.cost), "wall_s": wall, "safe": bool(rep.safe), "result_safe": bool(res.safe),
        "step_time_bound": rb.step_time, "continuous_bound": rb.continuous,
        "result_step_time": res.verification.get("risk_step_time"),
        "allotted": None if risk is None else risk.allotted, "result_bound": None if risk is None else risk.bound,
        "mc_runs": mc.runs, "mc_step_rate": mc.step_hazard_runs / mc.runs, "mc_step_ci": [step_lo, step_hi],
        "mc_continuous_rate": mc.hazard_runs / mc.runs, "mc_continuous_ci": [cont_lo, cont_hi],
        "step_within": step_hi <= rb.step_time, "step_not_refuted": step_lo <= rb.step_time,
        "continuous_within": cont_hi <= rb.continuous,
    }


def _plan(sc, seed: int, alpha: float, **risk) -> tuple[object, str]:
    """(path or None, why not): one IG-RRT* plan of the study's size."""
    try:
        planned = bn.plan(sc, n_nodes=N_NODES, seed=seed, alpha=alpha, noise="per_step", **risk)
    except bn.BeliefNLPError as exc:
        return None, f"{type(exc).__name__}: {exc}"[:500]
    return (planned.path, "") if planned.success else (None, str(planned.message)[:500])


def run_case(name: str, seed: int, alpha: float, deltas, runs: int, substeps: int, method: str,
             replan: bool = False) -> list[dict]:
    """Plan once, then smooth at the fixed level and with every budget and
    allocation; ``replan``: the budgeted runs start from ``bn.plan(...,
    risk=Delta)`` instead (a plan meeting the budget)."""
    base = {"scenario": name, "seed": seed, "alpha": alpha, "K": K, "method": method}
    sc = scenario_for(name, seed)
    t = time.perf_counter()
    starts = {None: _plan(sc, seed, alpha)}
    base["plan_s"] = time.perf_counter() - t
    if starts[None][0] is None:
        return [{**base, "variant": "fixed", "delta": None, "status": "no plan", "message": starts[None][1]}]
    for d in deltas:
        starts[d] = _plan(sc, seed, alpha, risk=d) if replan else starts[None]
    rows = []
    variants = [("fixed", None)] + [(a, d) for d in deltas for a in ALLOCATIONS]
    for i, (variant, delta) in enumerate(variants):
        row = {**base, "variant": variant, "delta": delta, "replanned": replan and delta is not None}
        path, why = starts[delta]
        if path is None:
            rows.append({**row, "status": "no plan", "message": why})
            continue
        kwargs = {} if delta is None else {"risk": delta, "allocation": variant}
        t = time.perf_counter()
        try:
            # no fallback to one step per edge: costs compare at the same K only
            res = bn.smooth(sc, path, method=method, K=K, alpha=alpha, k_fallback=False, **kwargs)
        except bn.BeliefNLPError as exc:
            row.update(status="error", message=f"{type(exc).__name__}: {exc}"[:500], wall_s=time.perf_counter() - t)
            rows.append(row)
            continue
        row.update(measure(sc, res, time.perf_counter() - t, runs, substeps, mc_seed=1000 * seed + i))
        rows.append(row)
    return rows


def _median(values) -> float:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else float("nan")


def table(rows: list[dict], deltas) -> str:
    """The markdown summary (module doc), one line per (Delta, alpha), all scenarios pooled."""
    ok = [r for r in rows if r.get("status") not in (None, "error", "no plan") and "cost" in r]
    by = {(r["scenario"], r["seed"], r["alpha"], r["variant"], r["delta"]): r for r in ok}
    lines = ["| Delta | alpha | paths | cost optimal / uniform (median) | optimal < uniform by >= 15 % | "
             "cost optimal / fixed (median) | fixed chi2 certifies (median) | MC step rate / certified bound, median "
             "(max): optimal, uniform, fixed | MC refutes the bound (CP lower end > bound) | "
             "wall optimal / fixed, uniform / fixed (median) | errors |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for delta in deltas:
        for alpha in ALPHAS:
            cases = sorted({(r["scenario"], r["seed"]) for r in rows if r["alpha"] == alpha})
            ratio, vs_fixed, wall_o, wall_u, fixed_bound = [], [], [], [], []
            within = {v: [] for v in ("optimal", "uniform", "fixed")}
            refuted = 0
            errors = sum(1 for r in rows if r["alpha"] == alpha and r.get("status") in ("error", "no plan")
                         and r.get("delta") in (delta, None))
            for s, seed in cases:
                o, u, f = (by.get((s, seed, alpha, v, d)) for v, d in
                           (("optimal", delta), ("uniform", delta), ("fixed", None)))
                if o and u and o["K_used"] == u["K_used"]:
                    ratio.append(o["cost"] / u["cost"])
                for v, r in (("optimal", o), ("uniform", u), ("fixed", f)):
                    if r and r.get("mc_step_rate") is not None and r["step_time_bound"] > 0:
                        within[v].append(r["mc_step_rate"] / r["step_time_bound"])
                        refuted += int(r["mc_step_ci"][0] > r["step_time_bound"])
                if f:
                    fixed_bound.append(f["step_time_bound"])
                    if o and o["K_used"] == f["K_used"]:
                        vs_fixed.append(o["cost"] / f["cost"])
                    if o:
                        wall_o.append(o["wall_s"] / f["wall_s"])
                    if u:
                        wall_u.append(u["wall_s"] / f["wall_s"])
            share = ", ".join(f"{_median(w):.2f} ({max(w, default=float('nan')):.2f})" for w in within.values())
            n_mc = sum(len(w) for w in within.values())
            below = sum(1 for x in ratio if x <= 0.85)
            lines.append(f"| {delta:g} | {alpha:g} | {len(ratio)} | {_median(ratio):.3f} | {below}/{len(ratio)} | "
                         f"{_median(vs_fixed):.3f} | {_median(fixed_bound):.3g} | {share} | {refuted}/{n_mc} | {_median(wall_o):.2f}, {_median(wall_u):.2f} | "
                         f"{errors} |")
    return "\n".join(lines)


def _note(load0: float, load1: float, cpus: int, n_cases: int, n_rows: int, total: float) -> str:
    return (f"\n\nLoad average {load0:.2f} at the start, {load1:.2f} at the end ({cpus} CPUs); {n_cases} cases, "
            f"{n_rows} smoothed paths, {total:.0f} s. Costs pool both scenarios. The Monte-Carlo columns: the "
            f"simulated rate of being inside a hazard at a step time over the certified step-time bound (a "
            f"bound that holds keeps this <= 1 up to sampling noise), and how many paths' 95 % Clopper-Pearson "
            f"interval lies wholly above their bound (a refuted bound).\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="seed 0 and Delta in {0.05, 0.25} only")
    ap.add_argument("--seeds", default="0-9", help="seeds (and family maps): '0-9' or '0,3,7'")
    ap.add_argument("--runs", type=int, default=10_000, help="Monte-Carlo runs per path")
    ap.add_argument("--substeps", type=int, default=20, help="Monte-Carlo samples per transition")
    ap.add_argument("--method", default="auto", help="smoothing method (default auto)")
    ap.add_argument("--replan", action="store_true",
                    help="start the budgeted runs from bn.plan(..., risk=Delta) (a plan per Delta)")
    ap.add_argument("--out", type=Path, default=None, help="JSON record (default results/risk[_quick].json)")
    ap.add_argument("--table", type=Path, default=None, help="only rewrite the table of this JSON record")
    args = ap.parse_args()
    if args.table is not None:
        rec = json.loads(args.table.read_text())
        md = table(rec["rows"], rec["settings"]["deltas"])
        rec["table"] = md
        args.table.write_text(json.dumps(rec, indent=2, default=float))
        m = rec["machine"]
        note = _note(m["load_average_start"][0], m["load_average_end"][0], m["cpus"],
                     len({(r["scenario"], r["seed"], r["alpha"]) for r in rec["rows"]}), len(rec["rows"]), m["total_s"])
        args.table.with_suffix(".md").write_text(md + note)
        print(md + note)
        return
    logging.disable(logging.WARNING)
    seeds = [0] if args.quick else parse_seeds(args.seeds)
    deltas = QUICK_DELTAS if args.quick else DELTAS
    out = args.out or Path(__file__).parent / "results" / ("risk_quick.json" if args.quick else "risk.json")
    load_start, t0 = os.getloadavg(), time.perf_counter()
    cases = [(s, seed, a) for s in SCENARIOS for seed in seeds for a in ALPHAS]
    rows: list[dict] = []
    with tqdm(cases, desc="risk study", unit="case") as bar:
        for name, seed, alpha in bar:
            bar.set_postfix_str(f"{name} seed {seed} alpha {alpha:g}")
            rows += run_case(name, seed, alpha, deltas, args.runs, args.substeps, args.method, args.replan)
    md = table(rows, deltas)
    record = {
        "benchmark": "end-to-end risk budget: optimal vs uniform allocation vs fixed chi2 (issue 20 item 4)",
        "settings": {"scenarios": SCENARIOS, "seeds": seeds, "alphas": ALPHAS, "deltas": deltas, "K": K,
                     "n_nodes": N_NODES, "planner_noise": "per_step", "method": args.method, "mc_runs": args.runs,
                     "mc_substeps": args.substeps, "mc_interval": "95 % Clopper-Pearson", "quick": args.quick,
                     "replan": args.replan},
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_average_start": load_start, "load_average_end": os.getloadavg(),
                    "total_s": time.perf_counter() - t0},
        "rows": rows,
        "table": md,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2, default=float))
    note = _note(load_start[0], os.getloadavg()[0], os.cpu_count(), len(cases), len(rows), time.perf_counter() - t0)
    out.with_suffix(".md").write_text(md + note)
    print(md + note)
    print(f"wrote {out} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
