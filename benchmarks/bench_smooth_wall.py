"""Wall time of ``smooth(method="auto")``: the first call of a process and warmed-up calls, with a breakdown.

Issue 21, item 5 and the ``auto`` wall target: the first call at most 0.3 s
above the others; in one process after a warm-up call, the median wall at most
0.15 s at K = 20 and 0.4 s at K = 40, the cost within 0.1 % of the old code's,
every answer verified. Paper-multi, per-step IG-RRT* plans with N = 500
(``bn.plan(sc, n_nodes=500, seed=s)``), alpha 0.1 and 1.0.

Each code version runs in a fresh process (a first call is only first once):

* ``import_s``: importing the package;
* ``first``: the first call (seed 0, alpha 0.1, K = 20), ``again``: the same
  call again, ``new_case``: another plan and alpha (seed 1, alpha 1.0) --
  before alpha became an NLP parameter that rebuilt every solver;
* ``first_K40``: the first K = 40 call (its solvers are built then);
* warmed-up cases: seeds 0..S-1 x alpha at K = 20 and 0..S40-1 at K = 40.

Every call's record has its wall time, cost, iterations, status, whether the
answer passed ``verify``, and a breakdown: warm start, problem set-up (the
start's exact check), solver construction, time inside the solver calls (IPOPT,
from the method's stats: function evaluations and the iteration callback
included), the exact checks of the solver's candidates, the history records,
the driver's finish (exact check, ``verify``, result) and the rest.

``--baseline DIR`` (a folder holding an older ``belief_nlp`` package, e.g.
``git archive 98e46e8 belief_nlp | tar -x -C /tmp/old98``) runs the old code
in its own processes too, alternating old and new ``--rounds`` times, and
pairs the cases (cost ratio new / old per case, wall ratios). Records go to
benchmarks/results/smooth_wall.json with the load averages:

    PYTHONPATH=$PWD python benchmarks/bench_smooth_wall.py --baseline /tmp/old98

``--compiled`` pairs the current code without a disk cache ("before") with
the current code on a warm disk cache whose derivative functions were
compiled (``BELIEF_NLP_CACHE_COMPILE=1``; the builds are waited for before
any timing):

    PYTHONPATH=$PWD python benchmarks/bench_smooth_wall.py --compiled --rounds 2 --label compiled
"""

from __future__ import annotations

import os

# One core per process: keep BLAS/OpenMP from spreading the small matrix work over threads.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _record import wait_for_compiled  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SCENARIO = "paper-multi"
ALPHAS = (0.1, 1.0)
PARTS = ("warm_start", "problem_setup", "build", "solver", "candidate_checks", "history", "finish", "other")


# ---------------------------------------------------------------- worker
def _import(baseline: str | None):
    """The package under test: the current ``belief_nlp`` or the one in
    ``baseline`` under the name ``belief_nlp_baseline`` (relative imports)."""
    if baseline is None:
        return importlib.import_module("belief_nlp")
    alias = Path(tempfile.mkdtemp(prefix="bench_baseline_"))
    (alias / "belief_nlp_baseline").symlink_to(Path(baseline).resolve() / "belief_nlp", target_is_directory=True)
    sys.path.insert(0, str(alias))
    return importlib.import_module("belief_nlp_baseline")


class Timers:
    """Wall seconds spent in a few named library functions (wrapped in place)."""

    def __init__(self, lib):
        self.t: dict[str, float] = defaultdict(float)
        mods = {n: sys.modules[f"{lib.__name__}.{n}"] for n in ("smoother.driver", "methods.nlp_engine")}
        for mod, name, part in ((mods["smoother.driver"], "_warm_start", "warm_start"),
                                (mods["smoother.driver"], "SmoothingProblem", "problem_setup"),
                                (mods["smoother.driver"], "_finish", "finish"),
                                # the engine's names before and after session 20 (a baseline tree may be older)
                                (mods["methods.nlp_engine"], "_safe_points", "candidate_checks"),
                                (mods["methods.nlp_engine"], "safe_points", "candidate_checks"),
                                (mods["methods.nlp_engine"], "_record_attempt", "history"),
                                (mods["methods.nlp_engine"], "record_attempt", "history")):
            if hasattr(mod, name):
                setattr(mod, name, self._wrap(getattr(mod, name), part))

    def _wrap(self, f, part):
        @functools.wraps(f)
        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self.t[part] += time.perf_counter() - t0
        return timed


def _nlp_stats(stats: dict) -> dict:
    """The NLP stage's stats of an ``auto`` or ``ipopt`` result."""
    return stats.get("ipopt", stats) if isinstance(stats.get("ipopt"), dict) else stats


def _call(lib, timers: Timers, sc, path, K: int, alpha: float, label: str) -> dict:
    timers.t.clear()
    t0, c0 = time.perf_counter(), time.process_time()
    res = lib.smooth(sc, path, method="auto", K=K, alpha=alpha)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = _nlp_stats(res.stats)
    parts = {p: float(timers.t.get(p, 0.0)) for p in PARTS}
    parts["build"] = float(st.get("build_time", 0.0))
    parts["solver"] = float(sum(a.get("wall_time", 0.0) for a in st.get("attempts", [])))
    parts["other"] = wall - sum(v for k, v in parts.items() if k != "other")
    return {"case": label, "K": K, "alpha": alpha, "wall": wall, "cpu": cpu, "cost": float(res.cost), "status": res.status,
            "method": res.method, "verified": bool(res.verification.get("safe")),
            "iterations": int(res.stats.get("iter_count", -1)), "parts": parts}


def worker(baseline: str | None, seeds: int, seeds40: int) -> dict:
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    lib = _import(baseline)
    import_s = time.perf_counter() - t0
    timers = Timers(lib)
    sc = lib.load_scenario(SCENARIO)
    paths = {s: lib.plan(sc, n_nodes=500, seed=s).path for s in range(max(seeds, seeds40, 2))}
    out = {"version": getattr(lib, "__version__", "?"), "import_s": import_s, "load_start": load0,
           "first": _call(lib, timers, sc, paths[0], 20, 0.1, "s0-a0.1"),
           "again": _call(lib, timers, sc, paths[0], 20, 0.1, "s0-a0.1"),
           "new_case": _call(lib, timers, sc, paths[1], 20, 1.0, "s1-a1.0"), "cases": []}
    for K, n in ((20, seeds), (40, seeds40)):
        if K == 40 and n:
            out["first_K40"] = _call(lib, timers, sc, paths[0], 40, 0.1, "s0-a0.1")
        for s in range(n):
            for a in ALPHAS:
                out["cases"].append(_call(lib, timers, sc, paths[s], K, a, f"s{s}-a{a}"))
    out["load_end"] = os.getloadavg()
    return out


# ---------------------------------------------------------------- driver
def _run_worker(baseline: Path | None, args, env: dict | None = None) -> dict:
    cmd = [sys.executable, __file__, "--worker", "--seeds", str(args.seeds), "--seeds40", str(args.seeds40)]
    if baseline is not None:
        cmd += ["--baseline", str(baseline)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env or _plain_env())
    return json.loads(out.stdout.strip().splitlines()[-1])


def _plain_env() -> dict:
    """The environment without a disk cache (each version builds its own solvers)."""
    return {k: v for k, v in os.environ.items() if k not in ("BELIEF_NLP_CACHE_DIR", "BELIEF_NLP_CACHE_COMPILE")}


def _compiled_env(args) -> dict:
    """A disk-cache folder with the derivative functions of every graph the
    worker builds compiled: one untimed worker fills it and starts the
    background builds, which are waited for."""
    folder = Path(tempfile.mkdtemp(prefix="bench_smooth_wall_compiled_"))
    env = {**_plain_env(), "BELIEF_NLP_CACHE_DIR": str(folder), "BELIEF_NLP_CACHE_COMPILE": "1"}
    _run_worker(None, args, env)
    wait_for_compiled(folder, len(list(folder.glob("*.nlp.pkl"))))
    return env


def _median(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def summarise(runs: list[dict]) -> dict:
    """Per version: medians over rounds of the first-call figures and, per K,
    of the warmed-up walls with the mean breakdown."""
    out = {"rounds": len(runs), "import_s": _median(r["import_s"] for r in runs)}
    for key in ("first", "again", "new_case", "first_K40"):
        if all(key in r for r in runs):
            out[key + "_wall"] = _median(r[key]["wall"] for r in runs)
            out[key + "_build"] = _median(r[key]["parts"]["build"] for r in runs)
    if "first_wall" in out:
        out["first_minus_again"] = _median(r["first"]["wall"] - r["again"]["wall"] for r in runs)
    cases = [c for r in runs for c in r["cases"]]
    for K in sorted({c["K"] for c in cases}):
        cs = [c for c in cases if c["K"] == K]
        out[f"K{K}"] = {"cases": len(cs), "median_wall": _median(c["wall"] for c in cs),
                        "median_cpu": _median(c.get("cpu", np.nan) for c in cs),
                        "median_iterations": _median(c["iterations"] for c in cs),
                        "verified": sum(c["verified"] for c in cs),
                        "answered_by": sorted({c["method"] for c in cs}),
                        "mean_parts": {p: float(np.mean([c["parts"][p] for c in cs])) for p in PARTS}}
    return out


def paired(before: list[dict], after: list[dict]) -> dict:
    """Cost ratio new / old per case (first round of each) and median wall ratios."""
    b = {(c["K"], c["case"]): c for c in before[0]["cases"]}
    ratios = [(c["cost"] / b[(c["K"], c["case"])]["cost"], c["K"], c["case"]) for c in after[0]["cases"]
              if (c["K"], c["case"]) in b]
    walls, cpus = defaultdict(list), defaultdict(list)
    for rb, ra in zip(before, after):
        for c in ra["cases"]:
            o = next((x for x in rb["cases"] if x["K"] == c["K"] and x["case"] == c["case"]), None)
            if o is not None:
                walls[c["K"]].append(c["wall"] / o["wall"])
                cpus[c["K"]].append(c["cpu"] / o["cpu"])     # CPU: the figure to read on a loaded machine
    return {"cost_ratio_max": max(r for r, _, _ in ratios), "cost_ratio_min": min(r for r, _, _ in ratios),
            "cost_ratios": [{"K": K, "case": case, "ratio": r} for r, K, case in ratios],
            "median_wall_ratio": {f"K{K}": _median(v) for K, v in walls.items()},
            "median_cpu_ratio": {f"K{K}": _median(v) for K, v in cpus.items()},
            "first_call_wall_ratio": _median(ra["first"]["wall"] / rb["first"]["wall"]
                                             for rb, ra in zip(before, after)),
            "new_case_wall_ratio": _median(ra["new_case"]["wall"] / rb["new_case"]["wall"]
                                           for rb, ra in zip(before, after))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="plans (seeds) at K = 20")
    ap.add_argument("--seeds40", type=int, default=3, help="plans (seeds) at K = 40")
    ap.add_argument("--rounds", type=int, default=1, help="fresh processes per version")
    ap.add_argument("--baseline", type=Path, default=None, help="folder holding an older belief_nlp package")
    ap.add_argument("--label", default="current", help="key of this run in the JSON file")
    ap.add_argument("--out", type=Path, default=RESULTS / "smooth_wall.json")
    ap.add_argument("--compiled", action="store_true",
                    help="pair the current code without a disk cache ('before') with the current code on a warm "
                         "disk cache whose derivative functions are compiled ('after'); no --baseline")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.compiled and args.baseline is not None:
        ap.error("--compiled compares the current code with itself: no --baseline")
    if args.worker:
        print(json.dumps(worker(None if args.baseline is None else str(args.baseline), args.seeds, args.seeds40)))
        return 0
    load0 = os.getloadavg()
    runs: dict[str, list[dict]] = {"after": []}
    if args.baseline is not None or args.compiled:
        runs["before"] = []
    envs = {"before": None, "after": _compiled_env(args) if args.compiled else None}
    for i in range(args.rounds):
        order = ["before", "after"] if i % 2 == 0 else ["after", "before"]
        for which in order:
            if which in runs:
                runs[which].append(_run_worker(args.baseline if which == "before" else None, args, envs[which]))
    doc = json.loads(args.out.read_text()) if args.out.exists() else {}
    entry = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load_start": load0,
                         "load_end": os.getloadavg()},
             "settings": {"scenario": SCENARIO, "nodes": 500, "alphas": ALPHAS, "seeds": args.seeds,
                          "seeds_K40": args.seeds40, "rounds": args.rounds,
                          "baseline": None if args.baseline is None else str(args.baseline),
                          "compiled": args.compiled},
             "summary": {k: summarise(v) for k, v in runs.items()}, "runs": runs}
    if "before" in runs:
        entry["paired"] = paired(runs["before"], runs["after"])
    doc[args.label] = entry
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1, default=float))
    print(json.dumps({k: v for k, v in entry.items() if k in ("machine", "summary")}, indent=1))
    if "paired" in entry:
        print(json.dumps({k: v for k, v in entry["paired"].items() if k != "cost_ratios"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
