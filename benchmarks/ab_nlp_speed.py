"""The issue-21 protocol of ``bench_nlp_speed.py`` run for two versions of
the code at once, case by case, so that the host's drift cancels.

This machine's speed drifts by up to 20 % within an hour (docs/numerics.md,
"One free variable more"), more than most changes are worth, so two records
taken one after the other compare the host as much as the code. Here each
version runs in its own warmed-up worker process (the code of a git revision
checked out in a temporary worktree, and the working tree), and every case
is timed in both, one right after the other, alternating which goes first.
The workers plan their own warm starts (the same when the planner did not
change).

Writes one JSON with both records (``bench_nlp_speed.py``'s format: "cases")
and :func:`compare_nlp_speed.compare`'s rows; prints that table.

    python benchmarks/ab_nlp_speed.py --before REV [--after REV] [--seeds 10 10 3] [--methods auto]
                                      [--random] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from compare_nlp_speed import compare, markdown

ROOT = Path(__file__).resolve().parents[1]
HERE = ROOT / "benchmarks" / "results"
KS = (20, 40, 80)
TAG = "@@ab "          # protocol lines on stdout; anything else a worker prints is passed over

# One worker: the benchmark's own case and run functions from its tree, a
# request (JSON) per line on stdin, its answer on one stdout line after TAG.
_WORKER = r"""
import json, sys
from bench_nlp_speed import _case, _run, _scenarios
import belief_nlp as bn
cases = {}
def case(family, seed, K):
    key = (family, seed, K)
    if key not in cases:
        _, sc, plan_seed = _scenarios(family, seed + 1)[seed]
        cases[key] = (sc, _case(sc, plan_seed, K))
    return cases[key]
for line in sys.stdin:
    req = json.loads(line)
    try:
        sc, ws = case(req["family"], req["seed"], req["K"])
        if ws is None:
            out = {"skipped": "no plan or warm start"}
        elif req["op"] == "warm":
            for a in (0.1, 1.0):
                bn.smooth(sc, ws, method=req["method"], alpha=a, time_limit=60.0)
            out = {"warmed": True}
        else:
            out = _run(sc, ws, req["method"], req["alpha"])
    except Exception as exc:          # a case that fails is recorded, the run goes on
        out = {"error": f"{type(exc).__name__}: {exc}"[:300]}
    print("@@ab " + json.dumps(out, default=float), flush=True)
"""


class Worker:
    """One version of the code in its own process, answering case requests."""

    def __init__(self, name: str, tree: Path):
        self.name, self.tree = name, tree
        env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
        self.proc = subprocess.Popen([sys.executable, "-u", "-c", _WORKER], cwd=tree / "benchmarks", env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask(self, **req) -> dict:
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        for line in self.proc.stdout:
            if line.startswith(TAG):
                return json.loads(line[len(TAG):])
        raise RuntimeError(f"worker {self.name} ({self.tree}) ended: exit {self.proc.wait()}")

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def _tree(rev: str | None, tmp: Path) -> Path:
    """The working tree for None, else ``rev`` checked out in a worktree under ``tmp``."""
    if rev is None:
        return ROOT
    path = tmp / rev.replace("/", "_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(path), rev], check=True,
                   capture_output=True)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="git revision of the code before")
    ap.add_argument("--after", default=None, help="git revision of the code after (default: the working tree)")
    ap.add_argument("--seeds", type=int, nargs=3, default=[10, 10, 3], metavar=("K20", "K40", "K80"))
    ap.add_argument("--methods", nargs="+", default=["auto"])
    ap.add_argument("--random", action="store_true", help="random-polygons maps too (as bench_nlp_speed.py)")
    ap.add_argument("--out", type=Path, default=HERE / "ab_nlp_speed.json")
    args = ap.parse_args()
    families = ["paper-multi"] + (["random-polygons"] if args.random else [])
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="belief_nlp_ab_") as tmp:
        trees = {"before": _tree(args.before, Path(tmp)), "after": _tree(args.after, Path(tmp))}
        workers = {k: Worker(k, v) for k, v in trees.items()}
        rows: dict[str, list] = {"before": [], "after": []}
        n = 0
        try:
            for fam in families:
                for K, n_seeds in zip(KS, args.seeds):
                    for seed in range(n_seeds):
                        for m in args.methods:
                            warm = {k: w.ask(op="warm", family=fam, seed=seed, K=K, method=m)
                                    for k, w in workers.items()}
                            if any("skipped" in v for v in warm.values()):
                                continue
                            for alpha in (0.1, 1.0):
                                order = ["before", "after"] if n % 2 == 0 else ["after", "before"]
                                n += 1
                                for k in order:
                                    r = workers[k].ask(op="run", family=fam, seed=seed, K=K, alpha=alpha, method=m)
                                    r.update(family=fam, seed=seed, K=K, alpha=alpha, method=m, first=order[0] == k)
                                    rows[k].append(r)
                                print(json.dumps({k: {f: rows[k][-1].get(f) for f in ("K", "seed", "alpha",
                                                                                       "iterations", "wall_s")}
                                                  for k in order}), flush=True)
        finally:
            for w in workers.values():
                w.close()
            for k, rev in (("before", args.before), ("after", args.after)):
                if rev is not None:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(trees[k])],
                                   capture_output=True)
    records = {k: {"revision": rev or "working tree", "cases": [r for r in v if "wall_s" in r],
                   "failed": [r for r in v if "wall_s" not in r]}
               for (k, v), rev in zip(rows.items(), (args.before, args.after))}
    table = compare(records["before"], records["after"])
    out = {"machine": {"cpus": os.cpu_count(), "loadavg_at_end": os.getloadavg()},
           "settings": vars(args) | {"out": str(args.out)}, "wall_s": time.perf_counter() - t0,
           **records, "comparison": table}
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1, default=float))
    print(markdown(table))


if __name__ == "__main__":
    main()
