"""Analysis of study records: a per-method table, performance profiles, anytime curves.

Conventions (after qpbenchmark and Dolan & More, "Benchmarking optimization
software with performance profiles", Math. Prog. 2002):

* a row **succeeds** when it returned a verified path (``safe``) and its
  status is not a failure; "converged" is counted separately, since a method
  stopped by its iteration limit still returns a valid path;
* **time** is the row's ``wall_time`` (planning + warm start + smoothing);
  a failed row is charged the largest time seen in the study, as qpbenchmark
  charges the time limit;
* the **shifted geometric mean** of times t_i with shift s is
  exp(mean(log(t_i + s))) - s (s = 1 s by default, so that sub-second rows
  do not dominate);
* the **cost ratio** of a row is its cost over the best cost of any method in
  the same case (failed rows: inf); the table shows its geometric mean over
  the cases where the method succeeded and the share of cases it was best
  (within 0.1 %);
* the **performance profile** of a method is rho(tau) = share of cases whose
  ratio (time or cost) to the case's best is <= tau.
"""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["method_table", "performance_profile", "anytime_curves", "shifted_geometric_mean", "table_markdown",
           "case_ratios"]

_FAILED = ("plan_failed", "warm_start_failed", "error", "timeout")


def shifted_geometric_mean(values, shift: float = 1.0) -> float:
    """exp(mean(log(v + shift))) - shift over the finite values (NaN if none)."""
    v = np.asarray(list(values), dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    return float(np.exp(np.mean(np.log(v + shift))) - shift)


def _ok(df):
    return df["safe"].astype(bool) & ~df["status"].isin(_FAILED)


def case_ratios(df, column: str = "cost"):
    """A (case x method) table of ``column`` over the case's best (inf where the row failed)."""
    import pandas as pd

    val = df[column].astype(float).where(_ok(df), np.inf)
    if column != "cost":      # times of failures: charged the largest time seen (module docstring)
        worst = df[column].astype(float)[np.isfinite(df[column].astype(float))].max()
        val = df[column].astype(float).where(_ok(df), worst if np.isfinite(worst) else np.inf)
    wide = pd.DataFrame({"case_key": df["case_key"], "method": df["method"], "v": val}).pivot_table(
        index="case_key", columns="method", values="v", aggfunc="first")
    best = wide.min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = wide.div(best.where(best > 0, np.nan), axis=0)
    # a case where every method failed says nothing about any of them
    return ratio[np.isfinite(best)].fillna(np.inf)


def method_table(df, shift: float = 1.0):
    """One row per method: cases, success rate, converged rate, shifted geometric
    mean of wall time, geometric-mean cost ratio to the best, share best,
    median cost and iterations, Monte-Carlo failure rate when recorded."""
    import pandas as pd

    ok = _ok(df)
    ratios = case_ratios(df, "cost")
    worst_time = df["wall_time"].astype(float)
    worst_time = worst_time[np.isfinite(worst_time)].max() if np.isfinite(worst_time).any() else math.nan
    out = []
    for method, g in df.groupby("method", sort=False):
        gok = ok[g.index]
        times = g["wall_time"].astype(float).where(gok, worst_time)
        r = ratios[method] if method in ratios else pd.Series(dtype=float)
        finite = r[np.isfinite(r)]
        row = {"method": method, "cases": int(g["case_key"].nunique()), "success": float(gok.mean()),
               "converged": float((g["status"] == "converged").mean()),
               "time_sgm_s": shifted_geometric_mean(times, shift),
               "cost_ratio_gm": float(np.exp(np.mean(np.log(finite)))) if len(finite) else math.nan,
               "best_share": float((r <= 1.001).mean()) if len(r) else math.nan,
               "median_cost": float(g["cost"].astype(float)[gok].median()) if gok.any() else math.nan,
               "median_iterations": float(g["iterations"].astype(float).median())}
        if "mc_rate" in g and g["mc_rate"].notna().any():
            runs = g["mc_runs"].astype(float).sum()
            row["mc_rate"] = float(g["mc_failures"].astype(float).sum() / runs) if runs else math.nan
        out.append(row)
    return pd.DataFrame(out)


def table_markdown(table) -> str:
    """A method table as Markdown (numbers rounded for reading)."""
    heads = {"method": "method", "cases": "cases", "success": "success", "converged": "converged",
             "time_sgm_s": "time (sgm, s)", "cost_ratio_gm": "cost / best (gm)", "best_share": "best",
             "median_cost": "median cost", "median_iterations": "median iters", "mc_rate": "MC failure rate"}
    cols = [c for c in heads if c in table.columns]
    lines = ["| " + " | ".join(heads[c] for c in cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for _, r in table.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if c in ("success", "converged", "best_share"):
                cells.append("-" if v != v else f"{100 * v:.0f} %")
            elif isinstance(v, float):
                cells.append("-" if v != v else f"{v:.4g}")
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def performance_profile(df, column: str = "wall_time", taus=None):
    """Dolan--More profile: (taus, {method: rho(tau)}) from the per-case ratios of ``column``."""
    ratios = case_ratios(df, column)
    finite = ratios.to_numpy()[np.isfinite(ratios.to_numpy())]
    if taus is None:
        top = max(2.0, float(finite.max()) * 1.05) if finite.size else 2.0
        taus = np.geomspace(1.0, top, 200)
    return np.asarray(taus), {m: np.array([(ratios[m] <= t).mean() for t in taus]) for m in ratios.columns}


def anytime_curves(df, grid=None):
    """Median over cases of (best cost so far / the case's best final cost) against
    wall time, per method, from the rows' ``trace`` columns: (grid, {method: values})."""
    best = df[_ok(df)].groupby("case_key")["cost"].min()
    traces: dict[str, list] = {}
    tmax = 0.0
    for _, r in df[_ok(df)].iterrows():
        tr = json.loads(r["trace"]) if isinstance(r.get("trace"), str) else []
        if tr and r["case_key"] in best.index and best[r["case_key"]] > 0:
            t = np.array([p[0] for p in tr])
            c = np.array([p[1] for p in tr]) / best[r["case_key"]]
            traces.setdefault(r["method"], []).append((t, c))
            tmax = max(tmax, float(t[-1]))
    if grid is None:
        grid = np.geomspace(0.05, max(tmax * 1.05, 0.1), 100)
    out = {}
    for m, items in traces.items():
        vals = np.full((len(items), len(grid)), np.inf)
        for i, (t, c) in enumerate(items):
            idx = np.searchsorted(t, grid, side="right") - 1     # last point at or before each time
            vals[i, idx >= 0] = c[idx[idx >= 0]]
        out[m] = np.median(vals, axis=0)
    return np.asarray(grid), out
