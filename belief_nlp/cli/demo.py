"""``belief-nlp demo``: the paper's experiment (section V) on paper-multi --
IG-RRT* then CCP for each alpha, Figs. 2-4, GIFs and a summary."""

from __future__ import annotations

import json
import time
from typing import Any

from ..errors import BeliefNLPError, ValidationError
from .common import (EXIT_FAILED, EXIT_OK, PAPER_METHOD, _fail, _fmt_alpha, _load_scenario, _one_line, _Run,
                     _save_path, _wrap)
from .figures import _no_path_panel, _panels, _save_fig
from .parser import _nonneg_float, _output_args, _planner_args, _smoother_args
from .plan import _plan
from .smooth import _accepted_costs, _smooth, _smooth_failed, _status_line


#: Rewiring-radius cap of the demo's planner (cost units). The scenario's 0.3
#: suits per-metre noise; with per-step noise (the smoother's model) an edge
#: out of a well-localised node costs about alpha/2 log det((P + W) P^-1)
#: whatever its length, and at alpha = 1 no neighbour lies within 0.3.
DEMO_MAX_RADIUS = 1.5


def add_parser(sub) -> None:
    """Add the ``demo`` subcommand to the subparsers ``sub``."""
    dp = sub.add_parser(
        "demo", help="the paper's experiment: plan + smooth on paper-multi, Figs. 2-4 and a GIF",
        description="Reproduce the paper's experiment (section V): IG-RRT* with N = 500 nodes on the "
                    "1 m x 1 m paper-multi scenario (W = 0.2e-3 I), for alpha = 0.1 and 1.0, then 15 CCP "
                    "iterations (--converged: until the cost stops falling). Writes into OUT: "
                    "fig2_planner_paths.png, fig3_smoothed_paths.png, fig4_cost_history.png, "
                    "smoothing_alpha<A>.gif, plan_alpha<A>.json|npz, smooth_alpha<A>.json, "
                    "smoothed_path_alpha<A>.json|npz and summary.json (costs, statuses, timings). "
                    "Exit code 3 if planning or smoothing failed for some alpha (the figures show the rest).",
        epilog="Examples:\n  belief-nlp demo --out demo_out\n  belief-nlp demo --converged --out demo_conv\n"
               "  belief-nlp demo --quick --out /tmp/demo   # seconds, for tests")
    dp.add_argument("--scenario", default="paper-multi", help="built-in scenario name or a .toml/.json file")
    dp.add_argument("--alphas", type=_nonneg_float, nargs="+", default=[0.1, 1.0], metavar="ALPHA",
                    help="information weights, one column of figures each")
    _planner_args(dp, max_radius=DEMO_MAX_RADIUS)
    _smoother_args(dp, max_iter=15, method=False)
    dp.add_argument("--converged", action="store_true",
                    help="run CCP until converged (up to 200 iterations) instead of the paper's 15")
    dp.add_argument("--no-gif", dest="gif", action="store_false", help="skip the GIFs of the smoothing")
    dp.add_argument("--quick", action="store_true",
                    help="small settings for tests: 150 nodes, 3 CCP iterations, low-resolution figures")
    _output_args(dp, out_default="demo_out")
    dp.set_defaults(func=_cmd_demo)


def _cmd_demo(run: _Run) -> int:
    import numpy as np

    a = run.args
    if a.quick:
        a.nodes = min(a.nodes, 150) if a.nodes == 500 else a.nodes
        a.max_iter = min(a.max_iter, 3) if a.max_iter == 15 else a.max_iter
        a.dpi = min(a.dpi, 60)
    if a.converged:
        a.max_iter = max(a.max_iter, 200)
    base = _load_scenario(a.scenario, None)
    run.prepare_out()
    t_demo = time.perf_counter()
    alphas = list(dict.fromkeys(a.alphas))
    runs: list[dict] = []
    failures: list[str] = []
    for alpha in alphas:
        entry, failure = _plan_and_smooth(run, base.with_options(alpha=alpha))
        runs.append(entry)
        if failure is not None:
            failures.append(failure)
    _demo_figures(run, base, runs)

    summary = {
        "scenario": base.name, "nodes": a.nodes, "seed": a.seed, "noise": a.noise, "metric": a.metric,
        "max_radius": a.max_radius,
        "max_iter": a.max_iter, "tol": a.tol, "horizon": a.horizon, "quick": a.quick,
        "W": np.asarray(base.W).tolist(), "total_time_s": time.perf_counter() - t_demo,
        "runs": [_run_summary(e) for e in runs], "failures": failures,
    }
    run.write_text("summary.json", json.dumps(summary, indent=1, allow_nan=True))
    run.list_written()
    for e in runs:
        s = _run_summary(e)
        if s.get("smooth_status"):
            run.say(f"alpha = {_fmt_alpha(e['alpha'])}: planner cost {s['plan_cost']:.5g} ({s['plan_steps']} steps); "
                    f"CCP {s['smooth_status']} after {s['smooth_iterations']} iterations: steering cost "
                    f"{s['initial_cost']:.5g} -> {s['smooth_cost']:.5g}")
    run.say(f"demo finished in {summary['total_time_s']:.1f} s")
    if failures:
        for f in failures:
            _fail(_one_line(f))
        return EXIT_FAILED
    return EXIT_OK


def _plan_and_smooth(run: _Run, sc) -> tuple[dict[str, Any], str | None]:
    """IG-RRT* then CCP on ``sc`` (one alpha), writing the plan, the smoothing
    result, the smoothed path and the GIF. Returns the run's entry and what
    failed (None if nothing)."""
    from ..plotting import animate_smoothing

    a = run.args
    alpha = sc.alpha
    tag = f"alpha{_fmt_alpha(alpha)}"
    label = f"[alpha = {_fmt_alpha(alpha)}] "
    entry: dict[str, Any] = {"alpha": alpha, "scenario": sc, "plan": None, "smooth": None}
    t0 = time.perf_counter()
    pres = _plan(run, sc, label=label, stem=f"plan_{tag}", figures=False)
    entry["plan"], entry["plan_time"] = pres, time.perf_counter() - t0
    if not pres.success:
        return entry, f"alpha = {_fmt_alpha(alpha)}: planning failed: {pres.message}"
    t0 = time.perf_counter()
    try:
        sres = _smooth(run, sc, pres.path, PAPER_METHOD, keep_iterates=a.gif, label=label)
    except BeliefNLPError as exc:
        if isinstance(exc, ValidationError):
            raise
        entry["error"] = str(exc)
        return entry, f"alpha = {_fmt_alpha(alpha)}: smoothing failed: {exc}"
    entry["smooth"], entry["smooth_time"] = sres, time.perf_counter() - t0
    run.wrote(sres.save(run.out / f"smooth_{tag}.json"))
    _save_path(run, sres.path, f"smoothed_path_{tag}")
    failure = f"alpha = {_fmt_alpha(alpha)}: {_status_line(sres)}" if _smooth_failed(sres) else None
    if a.gif and sres.iterates:
        t0 = time.perf_counter()
        titles = [f"alpha = {_fmt_alpha(alpha)}, CCP iteration {i}: cost "
                  f"{p.steering_cost(alpha):.5g}" for i, p in enumerate(sres.iterates)]
        gif, _ = animate_smoothing(sc, sres.iterates, run.out / f"smoothing_{tag}.gif", fps=3,
                                   titles=titles, dpi=min(a.dpi, 80))
        run.wrote(gif)
        entry["gif_time"] = time.perf_counter() - t0
    return entry, failure


def _demo_figures(run: _Run, base, runs: list[dict]) -> None:
    """Figs. 2 and 3 (planner and smoothed paths, one panel per alpha) and
    Fig. 4 (steering cost against CCP iteration)."""
    from ..plotting import plot_belief_path, plot_cost_history, plot_scenario

    a = run.args
    letters = "abcdefghijklmnopqrstuvwxyz"
    for fname, which in (("fig2_planner_paths.png", "plan"), ("fig3_smoothed_paths.png", "smooth")):
        fig, axes = _panels(len(runs), base.dim)
        for i, (ax, e) in enumerate(zip(axes, runs)):
            res = e[which]
            sc = e["scenario"]
            head = f"({letters[i % 26]}) alpha = {_fmt_alpha(e['alpha'])}"
            if res is not None and res.path is not None:
                plot_belief_path(sc, res.path, ax=ax, legend=(i == 0 and base.dim == 2))
                if which == "plan":
                    ax.set_title(f"{head}: IG-RRT*, N = {a.nodes}, {res.path.K} steps\nplanner cost {res.cost:.4g}",
                                 fontsize=9)
                else:
                    ax.set_title(f"{head}: after {res.nit} CCP iterations, K = {res.path.K}\nsteering cost "
                                 f"{res.initial_cost:.4g} -> {res.cost:.4g}", fontsize=9)
            else:
                plot_scenario(sc, ax=ax)
                reason = (e["plan"].message if e["plan"] is not None and not e["plan"].success
                          else e.get("error", "not run"))
                ax.set_title(f"{head}: no path", fontsize=9)
                _no_path_panel(ax, _wrap(reason, 40))
        fig.suptitle("Fig. 2: IG-RRT* path plans" if which == "plan" else "Fig. 3: smoothed path plans",
                     fontsize=10)
        _save_fig(run, fig, fname)

    histories = {f"alpha = {_fmt_alpha(e['alpha'])}": _accepted_costs(e["smooth"])
                 for e in runs if e["smooth"] is not None}
    fig, ax = plot_cost_history(histories or {"(no run)": []}, log=len(histories) > 1)
    ax.set_title("Fig. 4: steering cost vs CCP iteration", fontsize=10)
    _save_fig(run, fig, "fig4_cost_history.png")


def _run_summary(e: dict) -> dict:
    out: dict[str, Any] = {"alpha": e["alpha"]}
    p, s = e["plan"], e["smooth"]
    if p is not None:
        out.update(plan_success=p.success, plan_message=p.message, plan_time_s=e.get("plan_time"),
                   plan_cost=p.cost if p.success else None, plan_steps=p.path.K if p.path is not None else None,
                   first_solution_node=p.first_solution_iteration)
    if s is not None:
        out.update(smooth_status=s.status, smooth_message=s.message, smooth_iterations=s.nit,
                   initial_cost=s.initial_cost, smooth_cost=s.cost, smooth_steps=s.path.K,
                   cost_history=_accepted_costs(s), smooth_time_s=e.get("smooth_time"),
                   gif_time_s=e.get("gif_time"), safe=s.safe)
    if "error" in e:
        out["error"] = e["error"]
    return out
