"""Figure of the receding-horizon records: CPU seconds per re-plan after an
executed step, the last answer's graph with the step frozen against the
re-plan that builds the shorter horizon, per method and K (the records of
``bench_receding.py``; nothing is solved here).

    python benchmarks/plot_receding.py [--records receding receding_auto receding_ccp] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from _record import write_figure  # noqa: E402

HERE = Path(__file__).resolve().parent / "results"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", nargs="+", default=["receding", "receding_auto", "receding_ccp"])
    ap.add_argument("--out", type=Path, default=HERE / "receding.png")
    args = ap.parse_args()
    docs = [json.loads((HERE / f"{name}.json").read_text()) for name in args.records]
    Ks = sorted({r["K"] for d in docs for r in d["records"]})
    fig, axes = plt.subplots(1, len(Ks), figsize=(4.2 * len(Ks), 3.6), squeeze=False)
    for ax, K in zip(axes[0], Ks):
        labels, frozen, built = [], [], []
        for d in docs:
            rows = [r for r in d["records"] if r["K"] == K]
            if not rows:
                continue
            labels.append(d["args"]["method"])
            frozen.append([a["cpu_s"] for r in rows for a in r["frozen"] if "cpu_s" in a])
            built.append([b["cpu_s"] for r in rows for b in r["path"] if "cpu_s" in b])
        pos = range(len(labels))
        for data, shift, colour, name in ((built, -0.18, "tab:grey", "builds the shorter horizon"),
                                          (frozen, 0.18, "tab:blue", "bn.replan(advance=1): frozen")):
            ax.boxplot(data, positions=[p + shift for p in pos], widths=0.3, patch_artist=True,
                       boxprops={"facecolor": colour, "alpha": 0.6}, medianprops={"color": "k"},
                       flierprops={"markersize": 3})
            ax.plot([], [], "s", color=colour, alpha=0.6, label=name if ax is axes[0][0] else None)
        ax.set_xticks(list(pos), labels)
        ax.set_yscale("log")
        ax.set_title(f"K = {K}: a re-plan after each executed step", fontsize=9)
        ax.set_ylabel("CPU s per re-plan")
        ax.grid(True, axis="y", alpha=0.3)
    fig.legend(fontsize=8, loc="lower center", ncol=2)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    write_figure(fig, args.out)


if __name__ == "__main__":
    main()
