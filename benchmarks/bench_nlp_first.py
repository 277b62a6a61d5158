"""NLP first (issue 10, performance section): auto vs CCP vs IPOPT (vs SQP).

Two studies run with the library's own study runner (resumable records under
benchmarks/results/nlp_first/<name>/records.jsonl): paper-multi with planner
seeds 0..S-1, and S random-polygons maps with seed 0; alpha 0.1 and 1.0;
K = 20 (every method) and K = 40 (fewer seeds, no SQP: CasADi's Uno plug-in
hit the 300 s limit there); IG-RRT* with N = 500 nodes and per-step noise.
Every method smooths the same warm start. ``auto`` runs twice, without and with a short
CCP pass after a converged IPOPT answer (``ccp_polish``), to measure whether
that pass pays. Writes benchmarks/results/nlp_first.json (the per-method
table per K, the CCP-polish effect) and prints the Markdown table.

    python benchmarks/bench_nlp_first.py [--seeds 10] [--seeds40 5] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import belief_nlp as bn
from belief_nlp.study import Study, run_study
from belief_nlp.study.cases import Limits

HERE = Path(__file__).resolve().parent / "results"
METHODS = ["auto", "ccp", "ipopt", "sqp"]


def _studies(seeds: int, seeds40: int, methods: list[str]) -> dict[str, Study]:
    """K = 20: every method, ``seeds`` seeds (maps); K = 40: ``seeds40`` and no
    SQP (through CasADi's plug-in it hit the 300 s limit at K = 40)."""
    out = {}
    for K, n, ms in ((20, seeds, methods), (40, seeds40, [m for m in methods if m != "sqp"])):
        common = dict(alpha=[0.1, 1.0], K=[K], methods=ms, planner={"n_nodes": 500, "noise": "per_step"},
                      limits=Limits(time_limit=300), solver={"auto": {"ccp_polish": [0, 10]}, "ccp": {"max_iter": 300}})
        out[f"paper-multi-K{K}"] = Study(name=f"nlp-first-paper-K{K}", scenarios=["paper-multi"],
                                         seeds=list(range(n)), **common)
        out[f"random-polygons-K{K}"] = Study(name=f"nlp-first-random-K{K}", scenarios=[f"random-polygons:{n}"],
                                             seeds=[0], **common)
    return out


def _stat(row, key):
    try:
        st = json.loads(row["stats"]) if isinstance(row["stats"], str) else row["stats"]
    except (TypeError, ValueError):
        return np.nan
    v = st.get(key, np.nan) if isinstance(st, dict) else np.nan
    return float(v) if isinstance(v, (int, float)) else np.nan


def _table(df) -> list[dict]:
    """Per method: converged + verified, median iterations / CPU / wall, cost
    ratio to the best method per case (median, max, share within 1 %)."""
    ok = df["safe"].astype(bool)
    best = df[ok].groupby("case_key")["cost"].min()
    rows = []
    for m, g in df.groupby("method", sort=False):
        ratio = (g["cost"] / g["case_key"].map(best)).where(g["safe"].astype(bool), np.inf)
        cpu = g.apply(lambda r: _stat(r, "cpu_time"), axis=1)
        rows.append({"method": m, "cases": int(len(g)),
                     "converged_verified": int(((g["status"] == "converged") & g["safe"].astype(bool)).sum()),
                     "verified": int(g["safe"].astype(bool).sum()),
                     # the solver's own count (NLP: all stages; CCP: steps), not history rows
                     "median_iterations": float(g.apply(lambda r: _stat(r, "iter_count"), axis=1).median()),
                     "median_cpu_s": float(np.nanmedian(cpu)) if np.isfinite(cpu).any() else None,
                     "median_smooth_wall_s": float(g["smooth_time"].median()),
                     "median_ratio": float(np.median(ratio)), "max_ratio": float(np.max(ratio)),
                     "within_1pct": int((ratio <= 1.01).sum())})
    return rows


def _markdown(rows: list[dict]) -> str:
    out = ["| method | cases | converged & verified | verified | median its | median CPU s | "
           "median smooth wall s | cost / best: median | max | within 1 % |", "|---" * 10 + "|"]
    for r in rows:
        cpu = "-" if r["median_cpu_s"] is None else f"{r['median_cpu_s']:.2f}"
        out.append(f"| {r['method']} | {r['cases']} | {r['converged_verified']} | {r['verified']} | "
                   f"{r['median_iterations']:.0f} | {cpu} | {r['median_smooth_wall_s']:.2f} | "
                   f"{r['median_ratio']:.4f} | {r['max_ratio']:.4f} | {r['within_1pct']} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seeds40", type=int, default=5, help="seeds (maps) at K = 40")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=HERE / "nlp_first")
    args = ap.parse_args()
    import pandas as pd

    methods = [m for m in METHODS if m in bn.available_methods()]
    load = os.getloadavg()
    t0 = time.perf_counter()
    frames = []
    for name, study in _studies(args.seeds, args.seeds40, methods).items():
        run_study(study, args.out / name, workers=args.workers)
        df = bn.load_records(args.out / name)
        df["family"] = name.rsplit("-K", 1)[0]
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    res = {"machine": {"cpus": os.cpu_count(), "workers": args.workers, "loadavg_at_start": load,
                       "loadavg_at_end": os.getloadavg()},
           "settings": {"seeds": args.seeds, "seeds_K40": args.seeds40, "methods": methods, "nodes": 500,
                        "noise": "per_step", "time_limit_s": 300},
           "wall_s": time.perf_counter() - t0, "tables": {}}
    for K in sorted(df["K"].unique()):
        rows = _table(df[df["K"] == K])
        res["tables"][f"K={K}"] = rows
        print(f"\nK = {K}\n" + _markdown(rows))
    # the CCP pass after a converged IPOPT answer: how often, how much lower
    a0, a1 = (df[df["method"] == lab].set_index("case_key")["cost"] for lab in
              ("auto[ccp_polish=0]", "auto[ccp_polish=10]"))
    gain = ((a0 - a1) / a0).dropna()
    res["ccp_polish"] = {"cases": int(gain.size), "lower_by_0.1pct": int((gain > 1e-3).sum()),
                         "lower_by_1pct": int((gain > 1e-2).sum()), "max_gain": float(gain.max()) if gain.size else None}
    print("\nCCP polish after IPOPT:", res["ccp_polish"])
    HERE.mkdir(exist_ok=True)
    (HERE / "nlp_first.json").write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
