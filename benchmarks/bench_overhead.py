"""CPU time around the solver in warmed-up ``smooth(method="auto")`` calls, by part.

Issue 21 (speed): a warmed-up call on paper-multi spends ~75 % inside IPOPT;
this splits the rest. Per-step IG-RRT* plans with N = 500, seeds 0..S-1,
alpha 0.1 and 1.0, K = 20 and 40; one warm-up call per K, then every case
once, each part's CPU seconds (``time.process_time``) summed by wrapping the
library's functions in place:

* ``warm_start``: the driver's warm start;
* ``problem_setup``: the :class:`SmoothingProblem` (the start's exact check);
* ``ipopt``: the IPOPT calls (the solver's own work and CasADi's function
  evaluations) without the iteration callback;
* ``callback``: the Python side of the iteration callback (``Recorder.eval``
  or ``Recorder.eval_buffer``), per call and per IPOPT iteration (CasADi's
  conversion of its inputs to DMs, before the Python side, counts as ``ipopt``);
* ``candidate_checks`` and ``history``: the exact checks of the solver's
  candidates and the history records (``safe_points``, ``record_attempt``);
* ``ccp_polish``: the CCP polish after IPOPT (``ccp.run``);
* ``finish``: the driver's finish (exact check, ``verify``, result);
* ``other``: the rest (argument checks, the model, auto's own exact check).

``--cprofile FILE`` also writes a cProfile of the warmed K = 20 calls.
Run with the code under test on PYTHONPATH (one process per version):

    PYTHONPATH=$PWD python benchmarks/bench_overhead.py --label after --out /tmp/overhead.json
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import belief_nlp as bn  # noqa: E402

PARTS = ("warm_start", "problem_setup", "ipopt", "callback", "candidate_checks", "history", "ccp_polish", "finish",
         "other")


class CpuTimers:
    """CPU seconds in a few named library functions (wrapped in place; auto
    looks ``ccp.run`` up at call time). The callback runs inside the IPOPT
    calls and is subtracted from them; the other parts do not nest."""

    def __init__(self):
        self.t: dict[str, float] = defaultdict(float)
        self.n: dict[str, int] = defaultdict(int)
        drv = sys.modules["belief_nlp.smoother.driver"]
        eng = sys.modules["belief_nlp.methods.nlp_engine"]
        ccp = sys.modules["belief_nlp.methods.ccp"]
        rec = sys.modules["belief_nlp.methods.nlp_recorder"]
        for mod, name, part in ((drv, "_warm_start", "warm_start"), (drv, "SmoothingProblem", "problem_setup"),
                                (drv, "_finish", "finish"), (eng, "safe_points", "candidate_checks"),
                                (eng, "record_attempt", "history"), (ccp, "run", "ccp_polish")):
            setattr(mod, name, self._wrap(getattr(mod, name), part))
        # the callback's Python side: eval (DM inputs) or, where the recorder has it, eval_buffer
        name = "eval_buffer" if hasattr(rec.Recorder, "has_eval_buffer") and "eval_buffer" in vars(rec.Recorder) \
            else "eval"
        setattr(rec.Recorder, name, self._wrap(getattr(rec.Recorder, name), "callback"))
        self._wrap_solver(eng)

    def _wrap(self, f, part):
        @functools.wraps(f)
        def timed(*a, **k):
            c0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                self.t[part] += time.process_time() - c0
                self.n[part] += 1
        return timed

    def _wrap_solver(self, eng):
        """The IPOPT calls: the solver object's ``__call__`` inside ``_solve_stage``
        (the solver comes from ``solver_of``, as the engine imported it)."""
        solver_fn = eng.solver_of
        timers = self

        class Timed:
            def __init__(self, s):
                self._s = s

            def __call__(self, *a, **k):
                c0 = time.process_time()
                try:
                    return self._s(*a, **k)
                finally:
                    timers.t["ipopt_incl"] += time.process_time() - c0

            def __getattr__(self, name):
                return getattr(self._s, name)

        @functools.wraps(solver_fn)
        def wrapped(*a, **k):
            nlp, solver, recorder, build = solver_fn(*a, **k)
            return nlp, Timed(solver), recorder, build
        eng.solver_of = wrapped


def run(seeds: int, Ks: tuple[int, ...], profile: str | None) -> dict:
    timers = CpuTimers()
    sc = bn.load_scenario("paper-multi")
    paths = {s: bn.plan(sc, n_nodes=500, seed=s).path for s in range(seeds)}
    out: dict = {"load_start": os.getloadavg(), "cases": []}
    prof = cProfile.Profile(time.process_time) if profile else None
    for K in Ks:
        bn.smooth(sc, paths[0], K=K, alpha=0.1)                 # warm-up: solvers built
        for s in range(seeds):
            for a in (0.1, 1.0):
                timers.t.clear()
                timers.n.clear()
                if prof is not None and K == Ks[0]:
                    prof.enable()
                c0 = time.process_time()
                res = bn.smooth(sc, paths[s], K=K, alpha=a)
                cpu = time.process_time() - c0
                if prof is not None:
                    prof.disable()
                parts = {p: timers.t.get(p, 0.0) for p in PARTS}
                parts["ipopt"] = timers.t.get("ipopt_incl", 0.0) - parts["callback"]
                parts["other"] = cpu - sum(v for p, v in parts.items() if p != "other")
                ipopt_it = int(res.stats.get("ipopt", {}).get("iter_count", 0))
                out["cases"].append({"K": K, "seed": s, "alpha": a, "cpu": cpu, "parts": parts,
                                     "ipopt_with_callback": timers.t.get("ipopt_incl", 0.0),
                                     "callbacks": timers.n.get("callback", 0), "ipopt_iterations": ipopt_it,
                                     "cost": float(res.cost), "status": res.status,
                                     "iterations": int(res.stats.get("iter_count", -1)),
                                     "verified": bool(res.verification.get("safe"))})
    out["load_end"] = os.getloadavg()
    if prof is not None:
        prof.dump_stats(profile)
    out["summary"] = summary(out["cases"])
    return out


def summary(cases: list[dict]) -> dict:
    """Mean CPU ms per call and part, per K; the callback per IPOPT iteration."""
    res = {}
    for K in sorted({c["K"] for c in cases}):
        cs = [c for c in cases if c["K"] == K]
        n = len(cs)
        res[f"K{K}"] = {"cases": n, "cpu_ms": 1e3 * sum(c["cpu"] for c in cs) / n,
                        "parts_ms": {p: 1e3 * sum(c["parts"][p] for c in cs) / n for p in PARTS},
                        "callback_us_per_call": 1e6 * sum(c["parts"]["callback"] for c in cs)
                        / max(sum(c["callbacks"] for c in cs), 1),
                        "callbacks_per_call": sum(c["callbacks"] for c in cs) / n,
                        # the IPOPT calls with the callback (CasADi's side of it included), per iteration
                        "ipopt_with_callback_us_per_iteration": 1e6 * sum(c["ipopt_with_callback"] for c in cs)
                        / max(sum(c["callbacks"] for c in cs), 1),
                        "verified": sum(c["verified"] for c in cs)}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--K", default="20,40")
    ap.add_argument("--cprofile", default=None, help="write a cProfile of the warmed calls at the first K")
    ap.add_argument("--label", default="current")
    ap.add_argument("--out", type=Path, default=None, help="JSON file (the run is stored under --label)")
    args = ap.parse_args(argv)
    res = run(args.seeds, tuple(int(k) for k in args.K.split(",")), args.cprofile)
    res["package"] = bn.__file__
    print(json.dumps(res["summary"], indent=1))
    if args.out is not None:
        doc = json.loads(args.out.read_text()) if args.out.exists() else {}
        doc[args.label] = res
        args.out.write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
