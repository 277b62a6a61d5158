"""``belief-nlp compare``: smooth one path with several methods and tabulate them."""

from __future__ import annotations

import json
import math
from typing import Any

from ..errors import BeliefNLPError
from .common import EXIT_OK, FAILED_STATUSES, _fail, _Run, _save_path, log, smoothing_methods
from .figures import _panels, _plotted_costs, _save_fig
from .parser import _plan_unless_path_args, _scenario_arg, _smoother_args
from .smooth import _horizon, _scenario_and_path


def add_parser(sub) -> None:
    """Add the ``compare`` subcommand to the subparsers ``sub``."""
    methods = smoothing_methods()
    cp = sub.add_parser(
        "compare", help="smooth one path with several methods and tabulate cost, time, status",
        description=f"Smooth the same path with each method (default: every registered one, "
                    f"{', '.join(methods)}), from one shared warm start, and compare. Writes OUT/compare.json "
                    "(one record per method: status, cost, iterations, times, verification, history and path), "
                    "OUT/compare_path_<method>.json|npz (BeliefPath.load), OUT/compare.txt (the table, also printed), "
                    "OUT/compare.png (the smoothed paths) and OUT/compare_cost.png (cost per iteration). "
                    "Exit code 3 when every method failed.",
        epilog=f"Example:\n  belief-nlp compare paper-multi --path out/plan.json --methods {' '.join(methods)}")
    _scenario_arg(cp)
    cp.add_argument("--methods", nargs="+", choices=methods, default=list(methods),
                    help="methods to run")
    _smoother_args(cp, max_iter=None, method=False, path=True)
    _plan_unless_path_args(cp)
    cp.set_defaults(func=_cmd_compare)


def _cmd_compare(run: _Run) -> int:
    try:
        from ..comparison import compare, records_to_table
    except ImportError as exc:  # being built
        raise BeliefNLPError(f"the comparison module is not available in this installation ({exc})") from None
    a = run.args
    sc, path, code = _scenario_and_path(run)
    if path is None:
        return code
    log.info("comparing %s on %s", ", ".join(a.methods), sc.name or "scenario")
    K, why = _horizon(a.horizon, sc, path)
    log.info("K = %d (%s)", K, why)
    records = compare(sc, path, methods=tuple(a.methods), K=K, max_iter=a.max_iter, tol=a.tol,
                      solver=a.solver, time_limit=a.time_limit, progress=not run.quiet)
    table = records_to_table(records)
    run.write_text("compare.json", json.dumps(_jsonable(records), indent=1, allow_nan=True))
    run.write_text("compare.txt", table + "\n")
    for rec in records:
        p = _record_path(rec)
        if p is not None:
            _save_path(run, p, f"compare_path_{rec.get('method')}")
    _compare_figures(run, sc, path, records)
    run.list_written()
    if not run.quiet:
        print(table)
    if records and all(_record_failed(r) for r in records):
        return _fail("every method failed: " + "; ".join(
            f"{r.get('method')}: {r.get('status')}" for r in records))
    return EXIT_OK


def _record_failed(rec: dict) -> bool:
    return rec.get("status") in FAILED_STATUSES or rec.get("path") is None or rec.get("safe") is False


def _record_path(rec: dict):
    from ..path import BeliefPath

    p = rec.get("path")
    if p is None or isinstance(p, BeliefPath):
        return p
    if isinstance(p, dict):
        return BeliefPath.from_dict(p)
    return None


def _compare_figures(run: _Run, sc, path, records: list[dict]) -> None:
    from ..plotting import plot_belief_path, plot_cost_history

    fig, axes = _panels(len(records) + 1, sc.dim, size=4.2)
    plot_belief_path(sc, path, ax=axes[0])
    axes[0].set_title(f"initial: {path.K} steps", fontsize=9)
    histories = {}
    for ax, rec in zip(axes[1:], records):
        method = str(rec.get("method", "?"))
        p = _record_path(rec)
        if p is not None:
            plot_belief_path(sc, p, ax=ax)
            ax.set_title(f"{method}: {rec.get('status')}, cost {float(rec.get('cost', math.nan)):.4g}", fontsize=9)
        else:
            ax.set_title(f"{method}: {rec.get('status')}", fontsize=9)
        hist = rec.get("history")
        if hist:  # CCP: accepted iterates; IPOPT and auto: every iterate (feasible only near the end)
            histories[method] = _plotted_costs(method, ((h.get("cost"), h.get("accepted", True)) for h in hist))
    _save_fig(run, fig, "compare.png")
    if histories:
        fig, ax = plot_cost_history(histories, xlabel="iteration (CCP: convex solves; IPOPT: Newton steps; auto: both)",
                                    log=True, marker="")
        ax.set_title("steering cost per iteration", fontsize=9)
        _save_fig(run, fig, "compare_cost.png")


def _jsonable(obj: Any) -> Any:
    """Records -> JSON-friendly data (arrays to lists, objects with to_dict)."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if hasattr(obj, "to_dict"):
        return _jsonable(obj.to_dict())
    if hasattr(obj, "__dataclass_fields__"):
        from dataclasses import asdict

        return _jsonable(asdict(obj))
    return obj
