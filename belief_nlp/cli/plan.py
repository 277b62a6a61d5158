"""``belief-nlp plan``: run IG-RRT* and write the plan and its figures.

:func:`_plan` is also how ``smooth``, ``compare`` (without ``--path``) and
``demo`` obtain their paths.
"""

from __future__ import annotations

import time

from .common import EXIT_OK, _fail, _load_scenario, _one_line, _Run, _wrap, log
from .figures import _no_path_panel, _panels, _save_fig
from .parser import _output_args, _planner_args, _positive_float, _risk_args, _scenario_arg


def add_parser(sub) -> None:
    """Add the ``plan`` subcommand to the subparsers ``sub``."""
    pp = sub.add_parser(
        "plan", help="plan a minimum-sensing belief path with IG-RRT*",
        description="Run IG-RRT* on a scenario. Writes OUT/plan.json (or .npz): a PlanResult that "
                    "belief_nlp.planner.PlanResult.load reads back, with the path, the tree and the "
                    "best cost per node; OUT/plan.png (tree, path and confidence ellipses) and "
                    "OUT/plan_cost.png (best cost against nodes). Exit code 3 when no path is found.",
        epilog="Examples:\n  belief-nlp plan paper-multi --nodes 500 --alpha 0.1 --seed 0 --out out\n"
               "  belief-nlp plan paper-multi --risk 0.05 --out out_risk")
    _scenario_arg(pp)
    _planner_args(pp)
    pp.add_argument("--time-limit", type=_positive_float, default=None, metavar="SECONDS",
                    help="stop growing the tree after this wall time")
    _risk_args(pp)
    _output_args(pp)
    pp.set_defaults(func=_cmd_plan)


def _cmd_plan(run: _Run) -> int:
    a = run.args
    sc = _load_scenario(a.scenario, a.alpha, a.risk)
    run.prepare_out()
    res = _plan(run, sc)
    run.list_written()
    if not res.success:
        return _plan_failed(res)
    run.say(f"plan: planner cost {res.cost:.6g} (length {res.travel:.4g} m + {res.alpha:g} x information "
            f"{res.information:.4g} {res.info_unit}), {res.path.K} steps, first solution at node "
            f"{res.first_solution_iteration}")
    if res.risk is not None:
        run.say(f"plan: {_risk_line(res.risk)}")
    return EXIT_OK


def _risk_line(risk: dict) -> str:
    """The budget and what the plan certifies, for the report."""
    return (f"risk budget {risk['budget']:g}: certified collision bound {risk['bound']:.3g} at the step times "
            f"(collisions planned at chi2 = {risk['collision_chi2']:.4g}, target at {risk['target_chi2']:.4g}; "
            f"{len(risk['rounds'])} planning round(s))")


def _plan(run: _Run, sc, *, label: str = "", stem: str = "plan", figures: bool = True):
    """Plan with the args' planner options; write the result file (+ figures).
    Returns the PlanResult (successful or not)."""
    from ..planner import plan
    from ..planner.compiled import cold_compile_note

    a = run.args
    log.info("%splanning on %s with IG-RRT*: %d nodes, seed %d, alpha %g, %s noise, %s", label, sc.name or "scenario",
             a.nodes, a.seed, sc.alpha, a.noise, _radius_note(sc, a.max_radius, a.noise))
    note = cold_compile_note(a.backend, sc.dim, a.metric)
    if note:                                    # the planner logs it too, but below the CLI's default level
        log.info("%s%s", label, note)
    t0 = time.perf_counter()
    extra = {} if a.max_radius is None else {"max_radius": a.max_radius}
    res = plan(sc, n_nodes=a.nodes, seed=a.seed, metric=a.metric, noise=a.noise, time_limit=a.time_limit,
               branch_and_bound=a.branch_and_bound, backend=a.backend, progress=not run.quiet, **extra)
    elapsed = time.perf_counter() - t0
    run.wrote(res.save(run.out / f"{stem}.{a.format}"))
    if res.success:
        log.info("%splan: cost %.5g (%d steps, length %.3f m) in %.1f s", label, res.cost, res.path.K,
                 res.path.length, elapsed)
    else:
        log.info("%splanning failed after %.1f s: %s", label, elapsed, res.message)
    if figures:
        _plan_figures(run, sc, res, stem)
    return res


def _radius_note(sc, given: float | None, noise: str) -> str:
    """The rewiring-radius cap for the log: the value used and, when
    ``--max-radius`` differs from the scenario's ``[planner]`` value (the
    demo's own default does), the scenario's, so that two runs whose stated
    settings agree plan the same. ``noise``: the run's noise model (the
    cap's growth with alpha defaults by it)."""
    from ..planner.options import resolve_options

    # the scenario's values with the run's noise, validated as plan() does
    own = resolve_options(sc.planner, sc.alpha, sc.chi2, noise=noise)

    def cap(r: float) -> str:
        return f"{r:g}" + (f" + {own.radius_per_alpha:g} alpha" if own.radius_per_alpha else "")

    used = own.max_radius if given is None else given
    note = f"radius cap {cap(used)}" + (f" = {used + own.radius_per_alpha * sc.alpha:.3g}"
                                        if own.radius_per_alpha else "")
    if used != own.max_radius:
        note += f" (--max-radius; the scenario's [planner]: {cap(own.max_radius)})"
    return note


def _plan_figures(run: _Run, sc, res, stem: str) -> None:
    from ..plotting import plot_anytime, plot_belief_path, plot_scenario, plot_tree

    fig, ax = _panels(1, sc.dim, size=5.5)
    ax = ax[0]
    if res.tree is not None:
        plot_tree(sc, res.tree, ax=ax, path=res.path)
    else:
        plot_scenario(sc, ax=ax)
    if res.path is not None:
        plot_belief_path(sc, res.path, ax=ax, show_scenario=False, legend=sc.dim == 2)
        ax.set_title(f"IG-RRT* on {sc.name or 'scenario'}: {len(res.tree) if res.tree is not None else '?'} nodes, "
                     f"cost {res.cost:.4g}", fontsize=9)
    else:
        ax.set_title(f"IG-RRT* on {sc.name or 'scenario'}: no path", fontsize=9)
        _no_path_panel(ax, _wrap(res.message, 40))
    _save_fig(run, fig, f"{stem}.png")
    fig, ax = plot_anytime(res, xlabel="nodes in the tree", ylabel="best planner cost")
    ax.set_title("IG-RRT* best cost", fontsize=9)
    _save_fig(run, fig, f"{stem}_cost.png")


def _plan_failed(res) -> int:
    hint = " or a larger --risk" if res.risk is not None else ""
    return _fail(f"planning failed: {_one_line(res.message)} (try more --nodes, another --seed, a larger "
                 f"--max-radius{hint})")
