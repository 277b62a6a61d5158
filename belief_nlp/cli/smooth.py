"""``belief-nlp smooth``: smooth a belief path (auto, CCP or IPOPT), read from a file
or planned first; and the smoothing helpers ``compare`` and ``demo`` share."""

from __future__ import annotations

import time

from ..errors import BeliefNLPError, ValidationError
from .common import (EXIT_OK, FAILED_STATUSES, PAPER_METHOD, _fail, _load_input_path, _load_scenario, _one_line,
                     _Run, _save_path, iterates_feasible, log)
from .figures import _panels, _plotted_costs, _save_fig
from .parser import _plan_unless_path_args, _risk_args, _scenario_arg, _smoother_args
from .plan import _plan, _plan_failed


def add_parser(sub) -> None:
    """Add the ``smooth`` subcommand to the subparsers ``sub``."""
    ss = sub.add_parser(
        "smooth", help="smooth a belief path (auto, CCP or IPOPT), from a file or after planning",
        description="Smooth a feasible belief path toward a local optimum of the paper's problem. The path "
                    "comes from --path (a plan result, a belief path or a smoothing result, JSON or NPZ) "
                    "or, without --path, from an IG-RRT* run with the planner options below. Writes "
                    "OUT/smooth.json (SmoothResult.load reads it), OUT/smoothed_path.json|npz "
                    "(BeliefPath.load), OUT/smooth.png (initial and smoothed paths), OUT/smooth_cost.png "
                    "(cost per iteration), with a risk budget OUT/smooth_risk.png (each transition's ellipses at "
                    "its own level and its allotted risk) and, with --gif, OUT/smoothing.gif. The default method, auto, runs "
                    "IPOPT on the exact NLP and falls back to CCP from the best safe point; the result "
                    "says which ran (auto:ipopt+ccp, auto:ipopt or auto:ccp). The status (converged, "
                    "max_iter, time_limit, ...) is printed; solver failures exit with code 3.",
        epilog="Examples:\n  belief-nlp smooth paper-multi --path out/plan.json\n"
               "  belief-nlp smooth paper-multi --path out/plan.json --method ccp --max-iter 15\n"
               "  belief-nlp smooth paper-multi --risk 0.05 --allocation uniform --out out_risk\n"
               "  belief-nlp smooth paper-multi --nodes 500 --alpha 1.0 --method ipopt --out out_ipopt")
    _scenario_arg(ss)
    _smoother_args(ss, path=True)
    ss.add_argument("--gif", action="store_true",
                    help="also write OUT/smoothing.gif, one frame per kept feasible iterate (CCP: every iteration)")
    _risk_args(ss, allocation=True)
    _plan_unless_path_args(ss)
    ss.set_defaults(func=_cmd_smooth)


def _cmd_smooth(run: _Run) -> int:
    from ..plotting import animate_smoothing, plot_belief_path, plot_cost_history
    from ..smoother.registry import iterations_counted

    a = run.args
    sc, path, code = _scenario_and_path(run)
    if path is None:
        return code
    res = _smooth(run, sc, path, a.method, keep_iterates=a.gif)
    run.wrote(res.save(run.out / "smooth.json"))
    _save_path(run, res.path, "smoothed_path")

    fig, axes = _panels(2, sc.dim)
    plot_belief_path(sc, path, ax=axes[0])
    axes[0].set_title(f"initial path: {path.K} steps", fontsize=9)
    plot_belief_path(sc, res.path, ax=axes[1], legend=sc.dim == 2)
    axes[1].set_title(f"{res.method.upper()} ({res.status}, {res.nit} it.): K = {res.path.K}, "
                      f"cost {res.cost:.4g}", fontsize=9)
    _save_fig(run, fig, "smooth.png")
    fig, ax = plot_cost_history({res.method.upper(): _accepted_costs(res)},
                                xlabel=f"{res.method.upper()} iteration", marker="o" if res.nit <= 60 else "")
    note = "" if iterates_feasible(res.method) else ", iterates feasible only near the end"
    ax.set_title(f"steering cost (alpha = {res.alpha:g}{note})", fontsize=9)
    _save_fig(run, fig, "smooth_cost.png")
    if res.risk is not None:
        from ..plotting import plot_risk_allocation

        fig, _ = plot_risk_allocation(sc, res)
        _save_fig(run, fig, "smooth_risk.png")
    if a.gif and res.iterates:
        gif, _ = animate_smoothing(sc, res.iterates, run.out / "smoothing.gif", dpi=min(a.dpi, 80),
                                   titles=_iterate_titles(res))
        run.wrote(gif)
    run.list_written()
    run.say(f"smooth: {_status_line(res)}; steering cost at K = {res.path.K}: {res.initial_cost:.6g} -> "
            f"{res.cost:.6g} (control {res.control:.4g} + {res.alpha:g} x information {res.information:.4g} nats), "
            f"{iterations_counted(res.nit, res.method)}")
    if res.risk is not None:
        run.say(f"smooth: {res.risk.summary()}")
    if _smooth_failed(res):
        return _fail(f"smoothing failed: {_status_line(res)}")
    return EXIT_OK


def _smooth(run: _Run, sc, path, method: str, *, keep_iterates: bool = False, label: str = "",
            options: dict | None = None):
    from ..smoother import get_method, smooth
    from ..smoother.registry import iterations_counted

    a = run.args
    K, why = _horizon(a.horizon, sc, path)
    log.info("%ssmoothing with %s: K = %d (%s), at most %s", label, method.upper(), K, why,
             iterations_counted(a.max_iter or get_method(method).max_iter, method))
    t0 = time.perf_counter()
    budget = {}
    if sc.risk is not None:            # the scenario's or --risk: the smoother allocates it
        budget = {"risk": sc.risk}
        if getattr(a, "allocation", None) is not None:
            budget["allocation"] = a.allocation
        if getattr(a, "risk_kind", None) is not None:
            budget["risk_kind"] = a.risk_kind
    try:
        res = smooth(sc, path, method=method, K=K, max_iter=a.max_iter, tol=a.tol, solver=a.solver,
                     time_limit=a.time_limit, keep_iterates=keep_iterates, progress=not run.quiet, **budget,
                     **(options or {}))
    except ImportError as exc:  # a method whose module is not installed
        raise BeliefNLPError(f"method {method!r} is not available in this installation: {exc}") from None
    log.info("%s%s: %s, cost %.6g after %d iterations in %.1f s", label, res.method.upper(), res.status,
             res.cost, res.nit, time.perf_counter() - t0)   # what they count: the line before
    return res


def _horizon(requested: int | None, sc, path) -> tuple[int, str]:
    """The smoother's K: --horizon if given; else the scenario's [horizon] K
    when the path fits in it; else one step per path edge."""
    if requested is not None:
        if requested < path.K:
            raise ValidationError("--horizon", f"the path has {path.K} edges; K = {requested} would drop vertices "
                                               f"(choose K >= {path.K}, or leave it out)")
        return requested, "--horizon"
    if sc.K is not None and sc.K >= path.K:
        return sc.K, "the scenario's horizon"
    if sc.K is not None:
        return path.K, f"one step per edge: the path has more edges than the scenario's horizon {sc.K}"
    return path.K, "one step per edge"


def _accepted_costs(res) -> list[float]:
    """Cost per iteration as drawn: plain CCP's accepted iterates (a rejected
    step is not part of the run); for IPOPT and auto every iterate, feasible or
    not (interior-point iterates become feasible only as IPOPT converges)."""
    return _plotted_costs(getattr(res, "method", PAPER_METHOD), ((h.cost, h.accepted) for h in res.history))


def _iterate_titles(res, prefix: str = "") -> list[str]:
    """GIF frame titles for ``res.iterates`` (the warm start, then every kept
    feasible iterate) naming the method that ran: plain CCP keeps every
    iterate, so frame i is CCP iteration i; other methods (IPOPT, auto) keep
    a few feasible ones, numbered among themselves."""
    paths = res.iterates or []
    n = len(paths) - 1
    titles = []
    for i, p in enumerate(paths):
        if iterates_feasible(res.method):
            what = f"{res.method.upper()} iteration {i}"
        else:
            what = f"{res.method}: " + ("warm start" if i == 0 else f"feasible iterate {i} of {n}")
        titles.append(f"{prefix}{what}: cost {p.steering_cost(res.alpha):.5g}")
    return titles


def _status_line(res) -> str:
    return f"{res.method}: {res.status} -- {_one_line(res.message)}"


def _smooth_failed(res) -> bool:
    return res.status in FAILED_STATUSES or not res.safe


def _obtain_path(run: _Run, sc):
    """The path to smooth: from --path, or by planning (exit code on failure)."""
    a = run.args
    if a.path is not None:
        path, info = _load_input_path(a.path)
        name = info.get("scenario")
        if name and sc.name and name != sc.name:
            log.warning("warning: %s was planned on scenario %r, smoothing on %r", a.path, name, sc.name)
        return path, None
    res = _plan(run, sc)
    if not res.success:
        return None, _plan_failed(res)
    return res.path, None


def _scenario_and_path(run: _Run):
    """The scenario (with --alpha), the output folder and the path to smooth.
    Returns (scenario, path, None), or (scenario, None, exit code) when
    planning failed (the files written so far listed)."""
    a = run.args
    sc = _load_scenario(a.scenario, a.alpha, getattr(a, "risk", None))      # compare has no --risk
    for flag in ("allocation", "risk_kind"):
        if getattr(a, flag, None) is not None and sc.risk is None:
            raise ValidationError(f"--{flag.replace('_', '-')}", "needs a risk budget (--risk, or a scenario file "
                                                                 "with risk)")
    run.prepare_out()
    path, code = _obtain_path(run, sc)
    if path is None:
        run.list_written()
    return sc, path, code
