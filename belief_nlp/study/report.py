"""``DIR/report.md`` and its figures from a study's records.

Sections: what ran (cases, rows, versions), the per-method table
(:func:`~belief_nlp.study.analysis.method_table`), per-scenario success and
median cost, performance profiles of time and cost, the anytime curves, the
Monte-Carlo failure rates next to the nominal rate (when recorded), and the
failures with their messages. Figures: ``profile_time.png``,
``profile_cost.png``, ``anytime.png``, ``cost_vs_time.png``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from .analysis import anytime_curves, method_table, performance_profile, table_markdown
from .records import load_records

__all__ = ["write_report"]


def _finish(fig, ax, xlabel: str, ylabel: str, title: str, path: Path) -> None:
    from ..plotting.ticks import plain_numbers

    ax.set_xscale("log")
    plain_numbers(ax.xaxis)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)


def _figure_profiles(df, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ..plotting.ticks import plain_numbers

    names = []
    for column, label, fname in (("wall_time", "wall time", "profile_time.png"), ("cost", "cost", "profile_cost.png")):
        taus, prof = performance_profile(df, column)
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for m, rho in prof.items():
            ax.step(taus, rho, where="post", label=m)
        ax.set_ylim(0, 1.02)
        _finish(fig, ax, f"tau ({label} / best {label} of the case)", "share of cases",
                f"Performance profile: {label}", out / fname)
        names.append(fname)
    grid, curves = anytime_curves(df)
    if curves:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for m, v in curves.items():
            ax.step(grid, np.where(np.isfinite(v), v, np.nan), where="post", label=m)
        _finish(fig, ax, "wall time from planning start, s", "median cost / best cost of the case",
                "Anytime: best cost so far", out / "anytime.png")
        names.append("anytime.png")
    ok = df[df["safe"].astype(bool)]
    if len(ok):
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for i, (m, g) in enumerate(ok.groupby("method", sort=False)):   # a marker each: equal costs stay apart
            ax.scatter(g["wall_time"].astype(float), g["cost"].astype(float), s=12, label=m, alpha=0.7,
                       marker="os^Dv<>"[i % 7])
        ax.set_yscale("log")
        plain_numbers(ax.yaxis)
        _finish(fig, ax, "total wall time (plan + warm start + smoothing), s", "cost (smoother's objective)",
                "Cost versus total wall time", out / "cost_vs_time.png")
        names.append("cost_vs_time.png")
    return names


def write_report(directory: str | os.PathLike, figures: bool = True) -> Path:
    """Write ``directory/report.md`` (and figures) from the records there; return its path."""
    out = Path(directory)
    df = load_records(out)
    lines = [f"# Study report: {out.name}", ""]
    if len(df) == 0:
        lines.append("No records yet.")
        (out / "report.md").write_text("\n".join(lines) + "\n")
        return out / "report.md"
    study = df["study"].iloc[0] if "study" in df else ""
    versions = json.loads(df["versions"].iloc[-1]) if "versions" in df else {}
    lines += [f"Study `{study}`: {df['case_key'].nunique()} cases, {len(df)} rows, "
              f"scenarios {', '.join(map(str, df['scenario'].unique()))}; "
              f"seeds {sorted(df['seed'].unique().tolist())}, alpha {sorted(df['alpha'].unique().tolist())}, "
              f"K {sorted({str(k) for k in df['K'].tolist()})}.",
              "Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()) + ".", ""]
    if "warm_start_fallback" in df and df["warm_start_fallback"].astype(bool).any():
        n = df[df["warm_start_fallback"].astype(bool)]["case_key"].nunique()
        lines += [f"{n} case(s) had no feasible K-step warm start and used one step per edge "
                  f"(column `warm_start_fallback`).", ""]
    lines += ["## Methods", "",
              "success = a verified path returned; time = total wall time (planning, warm start, smoothing), "
              "shifted geometric mean with shift 1 s, failures charged the largest time seen; cost / best = "
              "geometric mean over the cases of the cost over the best method's cost in the same case; "
              "best = share of cases where the method was within 0.1 % of the best; iters = the smoother's "
              "iterations in total (SmoothResult.nit: CCP steps; IPOPT iterations of both stages and restarts; "
              "auto: both), at most the variant's max_iter.", "",
              table_markdown(method_table(df)), ""]
    capped = df[df["status"] == "max_iter"]
    if len(capped):
        lines += [f"{len(capped)} row(s) stopped at their iteration limit before converging (status `max_iter`: "
                  f"{', '.join(f'{m} {n}' for m, n in capped['method'].value_counts(sort=False).items())}); their "
                  "paths are verified and count as successes, not as converged. Raise `max_iter` in the study's "
                  "`[solver.<method>]` table, or leave it out (each method's own limit), to compare converged "
                  "results.", ""]
    lines += ["## Per scenario", "", "| scenario | method | rows | success | median cost | median wall s |",
              "|---|---|---|---|---|---|"]
    ok = df["safe"].astype(bool)
    for (sc, m), g in df.groupby(["scenario", "method"], sort=True):
        gok = ok[g.index]
        med = g["cost"].astype(float)[gok].median() if gok.any() else math.nan
        lines.append(f"| {sc} | {m} | {len(g)} | {100 * gok.mean():.0f} % | {med:.4g} | "
                     f"{g['wall_time'].astype(float).median():.3g} |")
    lines.append("")
    if "mc_runs" in df and (df["mc_runs"].astype(float) > 0).any():
        mc = df[df["mc_runs"].astype(float) > 0]
        lines += ["## Monte-Carlo safety", "",
                  "Simulated runs that touched an obstacle, left the domain or ended outside the target "
                  "(belief_nlp.study.montecarlo), pooled per method, next to the nominal per-ellipse rate.", "",
                  "| method | paths | runs | failure rate | worst path [95 % CI] | nominal |", "|---|---|---|---|---|---|"]
        for m, g in mc.groupby("method", sort=False):
            runs = g["mc_runs"].astype(float).sum()
            rate = g["mc_failures"].astype(float).sum() / runs
            w = g.loc[g["mc_rate"].astype(float).idxmax()]
            lines.append(f"| {m} | {len(g)} | {int(runs)} | {rate:.4f} | {w['mc_rate']:.4f} "
                         f"[{w['mc_ci_low']:.4f}, {w['mc_ci_high']:.4f}] | {w['nominal_rate']:.3g} |")
        lines.append("")
    if figures:
        names = _figure_profiles(df, out)
        lines += ["## Figures", ""] + [f"![{n}]({n})" for n in names] + [""]
    failed = df[df["status"].isin(("plan_failed", "warm_start_failed", "error", "timeout"))]
    if len(failed):
        lines += ["## Failures", "", "| scenario | seed | alpha | method | status | why |", "|---|---|---|---|---|---|"]
        for _, r in failed.head(50).iterrows():
            why = str(r.get("error") or r.get("message") or "").replace("|", "/").replace("\n", " ")[:160]
            lines.append(f"| {r['scenario']} | {r['seed']} | {r['alpha']:g} | {r['method']} | {r['status']} | {why} |")
        if len(failed) > 50:
            lines.append(f"\n({len(failed) - 50} more in the records)")
        lines.append("")
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
