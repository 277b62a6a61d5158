"""Figure of issue-21 protocol records: per-case wall time, iterations and
time per iteration against K, per method, with the issue's targets drawn in
(the records of ``bench_nlp_speed.py``; nothing is solved here).

    python benchmarks/plot_nlp_speed.py [--records nlp_speed_session25b nlp_speed_sqp_session25] [--out FILE]

A method that appears in several records is drawn from the first that has it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib import ticker  # noqa: E402

from _record import write_figure  # noqa: E402

HERE = Path(__file__).resolve().parent / "results"
COLOURS = {"auto": "tab:blue", "ipopt": "tab:orange", "sqp": "tab:green", "fatrop": "tab:red", "ccp": "tab:purple"}
#: the issue's wall targets for `auto` (s) and the growth bound K = 80 / K = 40
TARGETS = {20: 0.15, 40: 0.4}
GROWTH = 2.2


def _cases(records: list[str]) -> dict[str, list[dict]]:
    """method -> its cases, each method from the first record that has it."""
    out: dict[str, list[dict]] = {}
    for name in records:
        cases = json.loads((HERE / f"{name}.json").read_text())["cases"]
        for m in dict.fromkeys(c["method"] for c in cases):
            out.setdefault(m, [c for c in cases if c["method"] == m])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", nargs="+", default=["nlp_speed_session25b", "nlp_speed_sqp_session25"])
    ap.add_argument("--out", type=Path, default=HERE / "nlp_speed_session25b.png")
    args = ap.parse_args()
    by_method = _cases(args.records)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.9))
    panels = (("wall_s", "wall s per call"), ("iterations", "iterations per call"),
              ("per_iteration_ms", "ms per iteration"))
    n_methods = len(by_method)
    for ax, (key, label) in zip(axes, panels):
        for i, (m, cases) in enumerate(by_method.items()):
            Ks = sorted({c["K"] for c in cases})
            shift = (i - (n_methods - 1) / 2) * 0.06
            med = []
            for K in Ks:
                vals = np.array([c[key] for c in cases if c["K"] == K and c.get(key) is not None], float)
                x = K * np.exp(shift + np.random.default_rng(K).uniform(-0.02, 0.02, vals.size))
                ax.scatter(x, vals, s=9, alpha=0.45, color=COLOURS.get(m, "k"), linewidths=0)
                med.append(np.median(vals))
            ax.plot(np.array(Ks) * np.exp(shift), med, "-o", color=COLOURS.get(m, "k"), ms=5,
                    label=f"{m} (median)" if ax is axes[0] else None)
        if key == "wall_s":
            for K, t in TARGETS.items():
                ax.plot([K / 1.15, K * 1.15], [t, t], "k-", lw=2)
            auto40 = [c["wall_s"] for c in by_method.get("auto", []) if c["K"] == 40]
            if auto40:
                ax.plot([80 / 1.15, 80 * 1.15], [GROWTH * np.median(auto40)] * 2, "k-", lw=2)
            ax.plot([], [], "k-", lw=2, label="issue 21's targets for auto")
        ax.set_xscale("log")
        ax.set_yscale("log")
        # 1-2-5 ticks in plain numbers: each panel spans one to two decades
        ax.yaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.set_xticks([20, 40, 80], ["20", "40", "80"])
        ax.minorticks_off()
        ax.set_xlabel("K (steps)")
        ax.set_ylabel(label)
        ax.grid(True, which="major", alpha=0.3)
    fig.legend(fontsize=8, loc="lower center", ncol=n_methods + 1)
    fig.suptitle("Issue-21 protocol: paper-multi and random-polygons, per-step N = 500 plans, alpha 0.1 and 1"
                 + " (SQP stopped at 10x IPOPT's wall)" * ("sqp" in by_method), fontsize=9)
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    write_figure(fig, args.out)


if __name__ == "__main__":
    main()
