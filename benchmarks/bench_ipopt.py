"""IPOPT ablations (docs/numerics.md, "IPOPT iterations" and "IPOPT iterations and K").

paper-multi, per-step IG-RRT* warm starts (N = 500), seeds and alphas; each
variant changes the defaults of ``method="ipopt"`` by options only. Records
per case: IPOPT iterations (all stages), restoration iterations, solver CPU
seconds, final cost, verified, and a summary of IPOPT's own iteration log per
stage (the iteration at which mu reached its floor, iterations with an
inertia correction, primal-infeasible iterations, median alpha_pr,
backtracking and watchdog steps).

Four studies:

* ``--study ablation`` (issue 10): K = 20, both alphas, the variants that
  led to the floored log-Cholesky stage and the polish; writes
  benchmarks/results/ipopt_ablation.json.
* ``--study k`` (issue 21, item 3): the same warm starts at several K, the
  defaults and the remedies tried against the growth of the iteration count
  with K; K = 10 and 80 (defaults only, seed 0); and a diagnostic: IPOPT
  restarted from its own converged answer (means and sensing), and from the
  answer's means with minimal sensing. Writes
  benchmarks/results/ipopt_k_scaling.json. Load averages are recorded per
  case (2 shared cores: CPU seconds are upper bounds).

* ``--study inertia`` (issue 21, item 3): IPOPT's inertia-correction
  heuristics (INERTIA_VARIANTS) on paper-multi (seeds 0..9) and the
  random-polygons family (maps 0..4), both alphas, K = 20 and 40; writes
  benchmarks/results/ipopt_inertia.json.
* ``--study polish`` (issue 21, item 3): the polish started from the first
  stage's multipliers or not (POLISH_VARIANTS), the same cases; writes
  benchmarks/results/ipopt_polish.json.

* ``--study floor`` (issue 21, item 3): the log-Cholesky stage's floor
  (FLOOR_VARIANTS) at K = 80 on paper-multi seeds 0..2 first, then the
  polish study's cases at K = 20 and 40; ``--auto`` adds auto's final cost;
  writes benchmarks/results/ipopt_floor.json. ``--study mu``: the same
  cases for MU_VARIANTS (ipopt_mu.json); ``--study scale``: for
  SCALE_VARIANTS, the means scaled in the log-Cholesky stage (ipopt_scale.json).

    python benchmarks/bench_ipopt.py [--study ablation|k|inertia|polish|floor|mu|scale] [--seeds 5] [--K 20] [--out FILE]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.methods import ipopt
from belief_nlp.methods.solver_logs import log_dir

HERE = Path(__file__).resolve().parent / "results"

VARIANTS = {
    "before: Cholesky NLP, adaptive mu (the previous default)": dict(formulation="cholesky", polish=0),
    "log-Cholesky floored at 1e-2, adaptive mu, no polish": dict(polish=0, solver_options={"mu_min": 1e-11}),
    "+ mu_min 1e-7": dict(polish=0),
    "+ polish (the default)": dict(),
    "log-Cholesky, monotone mu, + polish": dict(solver_options={"mu_strategy": "monotone", "mu_min": 1e-11}),
}

#: issue 21, item 3: each changes the defaults in one respect (solver options
#: reach both stages unless the polish's own settings override them)
K_VARIANTS = {
    "defaults": dict(),
    "floor 3e-3": dict(floor=3e-3),
    "mu_min 1e-5": dict(solver_options={"mu_min": 1e-5}),
    "probing mu oracle": dict(solver_options={"mu_oracle": "probing"}),
    "mu-based bound multipliers, mu_init 1e-5": dict(solver_options={"bound_mult_init_method": "mu-based",
                                                                     "mu_init": 1e-5}),
    "bound_push = bound_frac = 1e-2": dict(solver_options={"bound_push": 1e-2, "bound_frac": 1e-2}),
}

#: inertia correction (Waechter & Biegler 2006, section 3.1): after a corrected
#: iteration IPOPT first tries perturb_dec_fact x the last delta_w (1/3); after
#: an uncorrected one it starts at first_hessian_perturbation and multiplies
#: by perturb_inc_fact_first (100) until the inertia is right
INERTIA_VARIANTS = {
    "defaults (dec 1/3, first increase x100)": dict(),
    "dec 0.1, first increase x10": dict(solver_options={"perturb_dec_fact": 0.1, "perturb_inc_fact_first": 10.0}),
    "dec 0.1, first increase x10, kappa_d 0": dict(solver_options={"perturb_dec_fact": 0.1,
                                                                   "perturb_inc_fact_first": 10.0, "kappa_d": 0.0}),
    # session 12: every corrected iteration's first trial (delta_w / 3) failed
    # the inertia test (61 of 61, K = 20 seed 0); a smaller decrease tries
    # closer to the delta_w that worked
    "dec 0.5": dict(solver_options={"perturb_dec_fact": 0.5}),
    "dec 0.6": dict(solver_options={"perturb_dec_fact": 0.6}),
    "dec 0.75": dict(solver_options={"perturb_dec_fact": 0.75}),
}

#: the polish started from the first stage's multipliers (the default since
#: session 8) or without them (IPOPT ignores the multipliers it is given
#: unless warm_start_init_point is yes)
POLISH_VARIANTS = {
    "polish without multipliers (before)": dict(solver_options={"warm_start_init_point": "no"}),
    "polish from stage 1's multipliers (default)": dict(),
}

#: the floor of the log-Cholesky stage (L_ii >= floor, scaled units): the
#: default, the candidate of the K study (3e-3), and one on either side of
#: it (5e-3 between the two; 1e-3 whether the trend goes on)
FLOOR_VARIANTS = {
    "floor 1e-2 (default)": dict(floor=1e-2),
    "floor 5e-3": dict(floor=5e-3),
    "floor 3e-3": dict(floor=3e-3),
    "floor 1e-3": dict(floor=1e-3),
}

#: the barrier's floor of the log-Cholesky stage (1e-7 by default): at
#: K = 80 half of the steps end at a bound (mu at its floor, fraction to the
#: boundary 1 - mu); a larger floor keeps the iterates off the bounds. The
#: defaults' rows are the floor study's (the runs are deterministic)
MU_VARIANTS = {
    "mu_min 1e-6": dict(floor=1e-2, solver_options={"mu_min": 1e-6}),
}

#: the means scaled in the log-Cholesky stage (IPOPT solves for x / s): its
#: inertia correction delta_w I then damps the path's smooth modes s^2 times
#: less (docs/numerics.md, "K = 80: continuation and sensing pattern")
SCALE_VARIANTS = {
    "defaults": dict(),
    "scale_means 100": dict(scale_means=100.0),
}

_ROW = re.compile(r"^\s*(\d+)(r?)\s+\S+\s+(\S+)\s+\S+\s+(\S+)\s+\S+\s+(\S+)\s+\S+\s+(\S+?)([a-zA-Z]?)\s+(\d+)\s*$")


def _log_sizes() -> dict:
    return {f: os.path.getsize(f) for f in glob.glob(os.path.join(log_dir("ipopt"), "*.log"))}


def _new_log_text(before: dict) -> str:
    """What IPOPT wrote to its log files (file_print_level 5) since ``before``."""
    out = ""
    for f, size in sorted(_log_sizes().items(), key=lambda kv: os.path.getmtime(kv[0])):
        if size != before.get(f, 0):
            with open(f) as fh:
                fh.seek(before.get(f, 0))
                out += fh.read()
    return out


def log_summary(text: str) -> list[dict]:
    """Per IPOPT solve in ``text``: where its iterations went (iteration table columns)."""
    solves: list[list] = []
    for line in text.splitlines():
        if line.startswith("This is Ipopt"):
            solves.append([])
            continue
        m = _ROW.match(line)
        if m and solves:
            it, resto, inf_pr, lg_mu, lg_rg, a_pr, kind, ls = m.groups()
            solves[-1].append((int(it), bool(resto), float(inf_pr), float(lg_mu), lg_rg != "-", float(a_pr), kind,
                               int(ls)))
    out = []
    for rows in solves:
        r = rows[1:]                                   # iteration 0 is the start
        if not r:
            continue
        out.append({"iterations": len(r),
                    "mu_floor_at": next((x[0] for x in r if x[3] <= min(y[3] for y in r) + 0.05), None),
                    "regularised": sum(x[4] for x in r),
                    "infeasible_gt_1e-3": sum(x[2] > 1e-3 for x in r),
                    "median_alpha_pr": float(np.median([x[5] for x in r])),
                    "backtracked": sum(x[7] > 1 for x in r), "watchdog": sum(x[6] == "w" for x in r),
                    "restoration": sum(x[1] for x in r)})
    return out


def _smooth(sc, start, alpha: float, **kw) -> dict:
    load = os.getloadavg()[0]
    before = _log_sizes()
    r = bn.smooth(sc, start, method="ipopt", alpha=alpha, **kw)
    att = r.stats.get("attempts", [])
    return {"status": r.status, "cost": r.cost, "iterations": int(r.stats.get("iter_count", 0)),
            "stages": [[a["formulation"], a["return_status"], a["iter_count"]] for a in att],
            "restoration": int(sum(a["restoration"] or 0 for a in att)),
            "cpu_s": float(sum(a["cpu_time"] for a in att)), "build_s": float(r.stats.get("build_time", 0.0)),
            "verified": bool(r.path is not None and bn.verify(sc, r.path).safe),
            "polish": r.stats.get("polish_status", ""), "log": log_summary(_new_log_text(before)),
            "loadavg": load, "path": r.path}


def _summarise(rows: list[dict]) -> dict:
    its = [x["iterations"] for x in rows]
    return {"median_iterations": float(np.median(its)), "max_iterations": int(max(its)),
            "median_cpu_s": float(np.median([x["cpu_s"] for x in rows])),
            "converged": sum(x["status"] == "converged" for x in rows),
            "verified": sum(bool(x["verified"]) for x in rows), "cases": len(rows),
            "median_loadavg": float(np.median([x["loadavg"] for x in rows]))}


def ablation(args) -> dict:
    sc = bn.load_scenario("paper-multi")
    plans = {s: bn.plan(sc, n_nodes=500, seed=s, noise="per_step").path for s in range(args.seeds)}
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()}, "settings": vars(args),
           "variants": []}
    for name, kw in VARIANTS.items():
        ipopt.clear_cache()
        rows = []
        for s, path in plans.items():
            for alpha in (0.1, 1.0):
                rec = _smooth(sc, bn.warm_start(sc, path, K=args.K[0]), alpha, **kw)
                rec.pop("path")
                rows.append({"seed": s, "alpha": alpha, **rec})
        out["variants"].append({"name": name, "options": kw, **_summarise(rows), "rows": rows})
        v = out["variants"][-1]
        print(f"{name}: median {v['median_iterations']} (max {v['max_iterations']}) iterations, "
              f"{v['median_cpu_s']:.2f} s CPU, {v['converged']}/{v['cases']} converged, "
              f"{v['verified']}/{v['cases']} verified", flush=True)
    _cost_ratios(out["variants"], ("seed", "alpha"))
    return out


def _cost_ratios(variants: list[dict], key: tuple) -> None:
    """Each variant's cost relative to the best verified cost of all variants per case."""
    best: dict = {}
    for v in variants:
        for x in v["rows"]:
            if x["verified"]:
                k = tuple(x[c] for c in key)
                best[k] = min(best.get(k, np.inf), x["cost"])
    for v in variants:
        ratios = [x["cost"] / best[tuple(x[c] for c in key)] if x["verified"] else np.inf for x in v["rows"]]
        v["median_cost_ratio_to_best"] = float(np.median(ratios))
        v["max_cost_ratio_to_best"] = float(max(ratios))


def k_study(args) -> dict:
    sc = bn.load_scenario("paper-multi")
    plans = {s: bn.plan(sc, n_nodes=500, seed=s, noise="per_step").path for s in range(args.seeds)}
    alphas = (1.0, 0.1)
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()}, "settings": vars(args),
           "variants": [], "k_scaling": [], "restart_from_answer": []}
    for name, kw in K_VARIANTS.items():
        ipopt.clear_cache()
        for K in args.K:
            rows = []
            for s, path in plans.items():
                ws = bn.warm_start(sc, path, K=K)
                for alpha in alphas:
                    rec = _smooth(sc, ws, alpha, **kw)
                    answer = rec.pop("path")
                    rows.append({"seed": s, "alpha": alpha, "K": K, "start_information": float(ws.path.information),
                                 **rec})
                    if name == "defaults" and alpha == 1.0 and answer is not None:
                        out["restart_from_answer"].append(_restarts(sc, answer, K, s, rec))
            out["variants"].append({"name": name, "K": K, "options": kw, **_summarise(rows), "rows": rows})
            v = out["variants"][-1]
            print(f"{name}, K = {K}: median {v['median_iterations']} (max {v['max_iterations']}) iterations, "
                  f"{v['converged']}/{v['cases']} converged, {v['verified']}/{v['cases']} verified, "
                  f"load {v['median_loadavg']:.1f}", flush=True)
    for K in args.K:
        _cost_ratios([v for v in out["variants"] if v["K"] == K], ("seed", "alpha"))
    ipopt.clear_cache()
    for K in args.extra_K:                 # the growth itself: defaults, seed 0
        ws = bn.warm_start(sc, plans[0], K=K)
        for alpha in alphas:
            rec = _smooth(sc, ws, alpha)
            rec.pop("path")
            out["k_scaling"].append({"seed": 0, "alpha": alpha, "K": K, "start_information": float(ws.path.information),
                                     **rec})
            print(f"defaults, K = {K}, alpha {alpha}: {rec['iterations']} iterations ({rec['stages']}), "
                  f"cost {rec['cost']:.5f}, verified {rec['verified']}, load {rec['loadavg']:.1f}", flush=True)
    return out


def _plans(n_paper: int, n_maps: int) -> dict:
    """(map name, seed) -> (scenario, path): one per-step N = 500 plan on each
    of paper-multi seeds 0..n_paper-1 and random-polygons maps 0..n_maps-1
    (seed = map); maps without a plan are left out."""
    from belief_nlp.families import generate

    maps = [("paper-multi", s, bn.load_scenario("paper-multi")) for s in range(n_paper)]
    maps += [(f"random-polygons@{m}", m, generate("random-polygons", m)) for m in range(n_maps)]
    plans = {}
    for name, seed, sc in maps:
        plan = bn.plan(sc, n_nodes=500, seed=seed, noise="per_step")
        if plan.success:
            plans[name, seed] = (sc, plan.path)
    return plans


def _warm_starts(plans: dict, keys, K: int, out: dict) -> dict:
    """key -> (scenario, warm start at K); a plan without one is recorded in
    ``out["no_warm_start"]``, not smoothed."""
    ws = {}
    for key in keys:
        sc, path = plans[key]
        try:
            ws[key] = (sc, bn.warm_start(sc, path, K=K))
        except bn.InfeasibleStartError as exc:
            out.setdefault("no_warm_start", []).append({"map": key[0], "seed": key[1], "K": K, "error": str(exc)})
    return ws


def variant_study(args, variants: dict) -> dict:
    """``variants`` (name -> smooth keywords) on paper-multi and the
    random-polygons family (maps 0..n-1), each map with one per-step N = 500
    plan (seed = map), both alphas, at every K."""
    plans = _plans(args.seeds, args.maps)
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()}, "settings": vars(args),
           "variants": []}
    for K in args.K:
        ws = _warm_starts(plans, plans, K, out)
        for vname, kw in variants.items():
            ipopt.clear_cache()
            rows = []
            for (name, seed), (sc, w) in ws.items():
                for alpha in (0.1, 1.0):
                    rec = _smooth(sc, w, alpha, **kw)
                    rec.pop("path")
                    rows.append({"map": name, "seed": seed, "alpha": alpha, "K": K, **rec})
            out["variants"].append({"name": vname, "K": K, "options": kw, **_summarise(rows),
                                    "total_iterations": int(sum(x["iterations"] for x in rows)),
                                    "total_cpu_s": float(sum(x["cpu_s"] for x in rows)), "rows": rows})
            v = out["variants"][-1]
            print(f"{vname}, K = {K}: median {v['median_iterations']} (max {v['max_iterations']}), total "
                  f"{v['total_iterations']} iterations, {v['total_cpu_s']:.1f} s CPU, {v['converged']}/{v['cases']} "
                  f"converged, {v['verified']}/{v['cases']} verified, load {v['median_loadavg']:.1f}", flush=True)
        _cost_ratios([v for v in out["variants"] if v["K"] == K], ("map", "seed", "alpha"))
        for v in out["variants"]:
            if v["K"] == K:
                print(f"  {v['name']}: cost / best median {v['median_cost_ratio_to_best']:.6f}, "
                      f"max {v['max_cost_ratio_to_best']:.6f}", flush=True)
    return out


def _auto(sc, start, alpha: float, kw: dict) -> dict:
    """auto with the variant's method options for its IPOPT stage (its solver options as the run's)."""
    opts = {k: v for k, v in kw.items() if k != "solver_options"}
    r = bn.smooth(sc, start, method="auto", alpha=alpha, ipopt_options=opts, solver_options=kw.get("solver_options"))
    return {"status": r.status, "cost": r.cost, "method": r.method, "iterations": int(r.stats.get("iter_count", 0)),
            "cpu_s": float(r.stats.get("cpu_time", 0.0)),
            "verified": bool(r.path is not None and bn.verify(sc, r.path).safe)}


def floor_study(args, variants: dict | None = None) -> dict:
    """FLOOR_VARIANTS: the tail first (``--tail-K`` on paper-multi seeds
    0..``--tail-seeds``-1), then ``--K`` on paper-multi seeds 0..``--seeds``-1
    and random-polygons maps 0..``--maps``-1, both alphas; ``--auto`` adds
    auto's final cost and CPU per case. The record is rewritten after every
    (K, variant), so a partial run is kept."""
    path = args.out or HERE / f"ipopt_{args.study}.json"
    plans = _plans(max(args.seeds, args.tail_seeds), args.maps)
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_start": os.getloadavg()}, "settings": vars(args),
           "variants": []}
    runs = [(K, [k for k in plans if k[0] == "paper-multi" and k[1] < args.tail_seeds]) for K in args.tail_K]
    runs += [(K, [k for k in plans if k[0] != "paper-multi" or k[1] < args.seeds]) for K in args.K]
    for K, keys in runs:
        ws = _warm_starts(plans, keys, K, out)
        if variants is None:
            variants = {f"floor {f:g}": dict(floor=f) for f in args.floors} if args.floors else FLOOR_VARIANTS
        for vname, kw in variants.items():
            ipopt.clear_cache()
            rows = []
            for (name, seed), (sc, w) in ws.items():
                for alpha in (1.0, 0.1):
                    rec = _smooth(sc, w, alpha, **kw)
                    rec.pop("path")
                    row = {"map": name, "seed": seed, "alpha": alpha, "K": K,
                           "start_information": float(w.path.information), **rec}
                    if args.auto:
                        row["auto"] = _auto(sc, w, alpha, kw)
                    rows.append(row)
                    print(f"  {vname}, K = {K}, {name} {seed}, alpha {alpha}: {rec['stages']}, restoration "
                          f"{rec['restoration']}, {rec['cpu_s']:.2f} s CPU, cost {rec['cost']:.5f}"
                          + (f", auto {row['auto']['cost']:.5f}" if args.auto else "")
                          + f", load {rec['loadavg']:.1f}", flush=True)
            v = {"name": vname, "K": K, "options": kw, **_summarise(rows),
                 "total_iterations": int(sum(x["iterations"] for x in rows)),
                 "total_restoration": int(sum(x["restoration"] for x in rows)),
                 "total_cpu_s": float(sum(x["cpu_s"] for x in rows)),
                 "polish_converged": sum(x["polish"] == "Solve_Succeeded" for x in rows), "rows": rows}
            if args.auto:
                v["auto_total_cpu_s"] = float(sum(x["auto"]["cpu_s"] for x in rows))
            out["variants"].append(v)
            print(f"{vname}, K = {K}: median {v['median_iterations']} (max {v['max_iterations']}), total "
                  f"{v['total_iterations']} iterations ({v['total_restoration']} restoration), "
                  f"{v['total_cpu_s']:.1f} s CPU, {v['converged']}/{v['cases']} converged, "
                  f"{v['verified']}/{v['cases']} verified, polish converged {v['polish_converged']}, "
                  f"load {v['median_loadavg']:.1f}", flush=True)
            _floor_ratios([x for x in out["variants"] if x["K"] == K], args.auto)
            path.write_text(json.dumps(out, indent=1, default=_json))
        for v in out["variants"]:
            if v["K"] == K:
                print(f"  {v['name']}: cost / best median {v['median_cost_ratio_to_best']:.6f}, max "
                      f"{v['max_cost_ratio_to_best']:.6f}" + (f"; auto median {v['auto_median_cost_ratio_to_best']:.6f}"
                                                              f", max {v['auto_max_cost_ratio_to_best']:.6f}"
                                                              if args.auto else ""), flush=True)
    return out


def _floor_ratios(variants: list[dict], auto: bool) -> None:
    """Per row and variant: cost / the best verified cost of all variants of
    the case (IPOPT's; auto's against the best of IPOPT's and auto's)."""
    _cost_ratios(variants, ("map", "seed", "alpha"))
    best: dict = {}
    for v in variants:
        for x in v["rows"]:
            for r in ([x, x["auto"]] if auto else [x]):
                if r["verified"]:
                    k = (x["map"], x["seed"], x["alpha"])
                    best[k] = min(best.get(k, np.inf), r["cost"])
    for v in variants:
        for x in v["rows"]:
            k = (x["map"], x["seed"], x["alpha"])
            x["cost_ratio_to_best"] = x["cost"] / best[k] if x["verified"] else float("inf")
            if auto:
                x["auto"]["cost_ratio_to_best"] = x["auto"]["cost"] / best[k] if x["auto"]["verified"] \
                    else float("inf")
        if auto:
            r = [x["auto"]["cost_ratio_to_best"] for x in v["rows"]]
            v["auto_median_cost_ratio_to_best"], v["auto_max_cost_ratio_to_best"] = float(np.median(r)), float(max(r))


def _restarts(sc, answer, K: int, seed: int, first: dict) -> dict:
    """IPOPT from its own answer (means and sensing: ``sensing="path"``) and
    from the answer's means with minimal sensing."""
    rec = {"seed": seed, "K": K, "alpha": 1.0, "first_iterations": first["iterations"], "first_cost": first["cost"]}
    for mode in ("path", "minimal"):
        again = _smooth(sc, bn.warm_start(sc, answer, K=K, sensing=mode), 1.0)
        again.pop("path")
        rec[mode] = again
    print(f"  restart K = {K}, seed {seed}: first {first['iterations']}; from the answer "
          f"{rec['path']['stages']}; from its means, minimal sensing {rec['minimal']['stages']}", flush=True)
    return rec


def _json(o):
    return str(o) if isinstance(o, Path) else float(o)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--study", choices=("ablation", "k", "inertia", "polish", "floor", "mu", "scale"),
                    default="ablation")
    ap.add_argument("--maps", type=int, default=5, help="inertia study: random-polygons maps 0..n-1")
    ap.add_argument("--seeds", type=int, default=None, help="seeds 0..n-1 (ablation: 5, k: 3)")
    ap.add_argument("--K", type=int, nargs="*", default=None, help="ablation: 20; k: 20 40")
    ap.add_argument("--extra-K", type=int, nargs="*", default=[10, 80],
                    help="k study: further K for the defaults, seed 0 only")
    ap.add_argument("--tail-K", type=int, nargs="*", default=[80], help="floor study: K on paper-multi only, first")
    ap.add_argument("--tail-seeds", type=int, default=3, help="floor study: paper-multi seeds 0..n-1 at --tail-K")
    ap.add_argument("--floors", type=float, nargs="*", default=None,
                    help="floor study: these floors, not FLOOR_VARIANTS")
    ap.add_argument("--auto", action="store_true", help="floor study: auto's final cost and CPU per case too")
    ap.add_argument("--out", type=Path, default=None, help="the record (default: benchmarks/results/<study>.json)")
    args = ap.parse_args()
    if args.study == "ablation":
        args.seeds, args.K = args.seeds or 5, args.K or [20]
        out, name = ablation(args), "ipopt_ablation.json"
    elif args.study in ("floor", "mu", "scale"):
        args.seeds, args.K = 6 if args.seeds is None else args.seeds, [20, 40] if args.K is None else args.K
        out = floor_study(args, {"mu": MU_VARIANTS, "scale": SCALE_VARIANTS}.get(args.study))
        name = f"ipopt_{args.study}.json"
    elif args.study in ("inertia", "polish"):
        args.seeds, args.K = args.seeds or 10, args.K or [20, 40]
        out = variant_study(args, INERTIA_VARIANTS if args.study == "inertia" else POLISH_VARIANTS)
        name = f"ipopt_{args.study}.json"
    else:
        args.seeds, args.K = args.seeds or 3, args.K or [20, 40]
        out, name = k_study(args), "ipopt_k_scaling.json"
    out["machine"]["loadavg_at_end"] = os.getloadavg()
    out["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    path = args.out or HERE / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=_json))


if __name__ == "__main__":
    main()
