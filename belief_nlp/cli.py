"""The belief-nlp command line: plan, smooth, compare and reproduce the paper.

Minimum-sensing path planning in Gaussian belief space:

  scenarios  list the built-in scenarios, show one, export it or draw it
  plan       run IG-RRT* and write the plan (JSON/NPZ) and its figures
  smooth     smooth a path (CCP or IPOPT) read from a file, or plan first
  compare    smooth the same path with several methods and tabulate them
  demo       the paper's experiment on paper-multi: Figs. 2-4 and GIFs

Every subcommand takes ``--help``. Scenarios are built-in names (see
``belief-nlp scenarios``) or TOML/JSON files (docs/scenario_schema.md).

Exit codes: 0 success; 2 bad input (the reason on one line of stderr, no
traceback: unknown options, bad values, missing or malformed files); 3
planning or solving failed (the status on stderr; files written so far stay).

Progress (tqdm bars and log lines) goes to stderr, results to stdout;
``--quiet`` silences both but for errors, ``-v`` shows the solvers' logs.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from .errors import BeliefNLPError, ValidationError

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED", "FAILED_STATUSES"]

EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED = 0, 2, 3

#: Smoother statuses reported as failures (exit code 3). The others --
#: converged, max_iter, time_limit, non_monotone, infeasible_iterate -- end
#: with a verified path that the user asked for (an iteration or time budget)
#: or the best iterate before a rejected step, and exit 0 with the status shown.
FAILED_STATUSES = ("solver_failed", "ipopt_failed")

PROG = "belief-nlp"

#: Rewiring-radius cap of the demo's planner (cost units). The scenario's 0.3
#: suits per-metre noise; with per-step noise (the smoother's model) an edge
#: out of a well-localised node costs about alpha/2 log det((P + W) P^-1)
#: whatever its length, and at alpha = 1 no neighbour lies within 0.3.
DEMO_MAX_RADIUS = 1.5
log = logging.getLogger("belief_nlp.cli")


class _UsageError(Exception):
    """Raised instead of argparse's print-usage-and-exit, so main() can report one line."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors become one-line messages (exit code 2)."""

    def error(self, message: str):  # type: ignore[override]
        raise _UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


class _Formatter(argparse.HelpFormatter):
    """Wrap each paragraph of a description on its own, keep indented lines
    (examples) as written, and show defaults that say something."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        import textwrap

        out = []
        for para in text.strip().split("\n\n"):
            lines = para.splitlines()
            if any(line.startswith(" ") for line in lines[1:]) or para.startswith(" "):
                out.append("\n".join(indent + line for line in lines))
            else:
                out.append(textwrap.fill(" ".join(para.split()), width, initial_indent=indent,
                                         subsequent_indent=indent))
        return "\n\n".join(out)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("%(default)" not in text and action.option_strings and default is not None
                and not isinstance(default, bool) and default != argparse.SUPPRESS):
            shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else "%(default)s"
            text += f" (default: {shown})"
        return text


# ------------------------------------------------------------ value types
def _integer(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        value = minimum - 1
    if value < minimum:
        kind = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise argparse.ArgumentTypeError(f"must be {kind}, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    return _integer(text, 1)


def _nonneg_int(text: str) -> int:
    return _integer(text, 0)


def _number(text: str, positive: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        kind = "a number > 0" if positive else "a number >= 0"
        raise argparse.ArgumentTypeError(f"must be {kind}, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    return _number(text, positive=True)


def _nonneg_float(text: str) -> float:
    return _number(text, positive=False)


# ------------------------------------------------------------ the parser
def _common(p: argparse.ArgumentParser, out_default: str | None = "out") -> None:
    g = p.add_argument_group("output and progress")
    if out_default is not None:
        g.add_argument("--out", type=Path, default=Path(out_default), metavar="DIR",
                       help="folder for result files and figures (created if missing)")
        g.add_argument("--format", choices=("json", "npz"), default="json",
                       help="file format of plan results and belief paths (smoothing results are JSON)")
        g.add_argument("--dpi", type=_positive_int, default=150, help="resolution of the PNG figures")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bars or messages (errors still shown)")
    g.add_argument("-v", "--verbose", action="count", default=0,
                   help="show the planner's and smoother's log (-vv: debug)")


def _scenario_arg(p: argparse.ArgumentParser, default: str | None = None) -> None:
    if default is None:
        p.add_argument("scenario", help="built-in scenario name (see 'belief-nlp scenarios') or a .toml/.json file")
    else:
        p.add_argument("--scenario", default=default,
                       help="built-in scenario name or a .toml/.json file")
    p.add_argument("--alpha", type=_nonneg_float, default=None,
                   help="information weight alpha (cost = control + alpha * information); default: the scenario's")


def _planner_args(p: argparse.ArgumentParser, nodes: int = 500, title: str = "planner (IG-RRT*)",
                  max_radius: float | None = None) -> None:
    g = p.add_argument_group(title)
    g.add_argument("--nodes", type=_positive_int, default=nodes, help="nodes in the final tree (the paper's N)")
    g.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (same seed, same plan)")
    g.add_argument("--metric", choices=("entropy", "wasserstein", "hellinger"), default="entropy",
                   help="information term of the planner's edge cost")
    g.add_argument("--noise", choices=("per_step", "per_metre"), default="per_step",
                   help="planner's process noise: per_step adds W on every edge, the smoother's model (paper "
                        "eq. 2), so the plan can be smoothed as it is; per_metre adds W_rate per metre "
                        "travelled, as the authors' IG-RRT* (its paths may pass too close to obstacles "
                        "for the per-step model)")
    g.add_argument("--max-radius", type=_positive_float, default=max_radius, metavar="R",
                   help="cap of the rewiring radius, in cost units" + (
                       " (default: the scenario's [planner] value)" if max_radius is None else "")
                   + ". With per_step noise every edge pays for a full W, so a larger cap than the "
                     "per-metre one lets IG-RRT* connect at large alpha")
    g.add_argument("--no-branch-and-bound", dest="branch_and_bound", action="store_false",
                   help="do not prune nodes that cannot beat the best path")


def _smoother_args(p: argparse.ArgumentParser, max_iter: int | None = 50, method: bool = True,
                   path: bool = False) -> None:
    if path:
        p.add_argument("--path", type=Path, metavar="FILE",
                       help="the path to smooth: a plan result, belief path or smoothing result (.json/.npz); "
                            "without it, plan first")
    p.add_argument("--time-limit", type=_positive_float, default=None, metavar="SECONDS",
                   help="wall-time limit of each planning and each smoothing run (the best feasible path "
                        "found is kept)")
    g = p.add_argument_group("smoother")
    if method:
        g.add_argument("--method", choices=("ccp", "ipopt"), default="ccp",
                       help="ccp: convex-concave procedure (the paper's); ipopt: the same model by IPOPT")
    g.add_argument("--horizon", "-K", dest="horizon", type=_positive_int, default=None, metavar="K",
                   help="time steps of the smoothed path, at least the path's edge count (edges are cut into "
                        "equal steps); default: the scenario's [horizon] K if the path fits, else one step "
                        "per edge")
    g.add_argument("--solver", default="CLARABEL",
                   help="conic solver of the CCP subproblems (CLARABEL, or another CVXPY solver such as SCS)")
    g.add_argument("--max-iter", type=_positive_int, default=max_iter,
                   help="iteration limit of the smoother" + (
                       " (default: 100 for CCP, 3000 for IPOPT, whose iterations are Newton steps)"
                       if max_iter is None else ""))
    g.add_argument("--tol", type=_positive_float, default=1e-4,
                   help="stop when an iteration lowers the cost by less than this fraction")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``belief-nlp`` (errors raise instead of exiting)."""
    p = _Parser(prog=PROG, description=__doc__.split("Every subcommand")[0].strip(),
                formatter_class=_Formatter,
        epilog="Exit codes: 0 success, 2 bad input, 3 planning or solving failed.\n\n"
               "Start with:\n  belief-nlp demo --out demo_out\n  belief-nlp COMMAND --help")
    from . import __version__

    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    # scenarios -------------------------------------------------------------
    sp = sub.add_parser(
        "scenarios", help="list built-in scenarios, show, export or draw one", formatter_class=_Formatter,
        description="Without NAME: list the built-in scenarios. With NAME (a built-in or a file): print its "
                    "contents; --export writes it as TOML/JSON (a starting point for your own scenario), "
                    "--plot draws it.",
        epilog="Examples:\n  belief-nlp scenarios\n  belief-nlp scenarios paper-multi --export my.toml\n"
               "  belief-nlp scenarios my.toml --plot my.png")
    sp.add_argument("name", nargs="?", help="built-in name or scenario file")
    sp.add_argument("--export", type=Path, metavar="FILE", help="write the scenario to this .toml or .json file")
    sp.add_argument("--plot", type=Path, metavar="FILE", help="draw the scenario into this image (.png, .pdf, .svg)")
    _common(sp, out_default=None)
    sp.set_defaults(func=_cmd_scenarios)

    # plan ------------------------------------------------------------------
    pp = sub.add_parser(
        "plan", help="plan a minimum-sensing belief path with IG-RRT*", formatter_class=_Formatter,
        description="Run IG-RRT* on a scenario. Writes OUT/plan.json (or .npz): a PlanResult that "
                    "belief_nlp.planner.PlanResult.load reads back, with the path, the tree and the "
                    "best cost per node; OUT/plan.png (tree, path and confidence ellipses) and "
                    "OUT/plan_cost.png (best cost against nodes). Exit code 3 when no path is found.",
        epilog="Example:\n  belief-nlp plan paper-multi --nodes 500 --alpha 0.1 --seed 0 --out out")
    _scenario_arg(pp)
    _planner_args(pp)
    pp.add_argument("--time-limit", type=_positive_float, default=None, metavar="SECONDS",
                    help="stop growing the tree after this wall time")
    _common(pp)
    pp.set_defaults(func=_cmd_plan)

    # smooth ----------------------------------------------------------------
    ss = sub.add_parser(
        "smooth", help="smooth a belief path (CCP or IPOPT), from a file or after planning",
        formatter_class=_Formatter,
        description="Smooth a feasible belief path toward a local optimum of the paper's problem. The path "
                    "comes from --path (a plan result, a belief path or a smoothing result, JSON or NPZ) "
                    "or, without --path, from an IG-RRT* run with the planner options below. Writes "
                    "OUT/smooth.json (SmoothResult.load reads it), OUT/smoothed_path.json|npz "
                    "(BeliefPath.load), OUT/smooth.png (initial and smoothed paths), OUT/smooth_cost.png "
                    "(cost per iteration) and, with --gif, OUT/smoothing.gif. The status (converged, "
                    "max_iter, time_limit, ...) is printed; solver failures exit with code 3.",
        epilog="Examples:\n  belief-nlp smooth paper-multi --path out/plan.json --max-iter 15\n"
               "  belief-nlp smooth paper-multi --nodes 500 --alpha 1.0 --method ipopt --out out_ipopt")
    _scenario_arg(ss)
    _smoother_args(ss, path=True)
    ss.add_argument("--gif", action="store_true", help="also write OUT/smoothing.gif, one frame per iteration")
    _planner_args(ss, title="planner (only without --path)")
    _common(ss)
    ss.set_defaults(func=_cmd_smooth)

    # compare ---------------------------------------------------------------
    cp = sub.add_parser(
        "compare", help="smooth one path with several methods and tabulate cost, time, status",
        formatter_class=_Formatter,
        description="Smooth the same path with each method (default: ccp and ipopt), from one shared warm "
                    "start, and compare. Writes OUT/compare.json (one record per method: status, cost, "
                    "iterations, times, verification, history and path), OUT/compare_path_<method>.json|npz "
                    "(BeliefPath.load), OUT/compare.txt (the table, also printed), "
                    "OUT/compare.png (the smoothed paths) and OUT/compare_cost.png (cost per iteration). "
                    "Exit code 3 when every method failed.",
        epilog="Example:\n  belief-nlp compare paper-multi --path out/plan.json --methods ccp ipopt")
    _scenario_arg(cp)
    cp.add_argument("--methods", nargs="+", choices=("ccp", "ipopt"), default=["ccp", "ipopt"],
                    help="methods to run")
    _smoother_args(cp, max_iter=None, method=False, path=True)
    _planner_args(cp, title="planner (only without --path)")
    _common(cp)
    cp.set_defaults(func=_cmd_compare)

    # demo ------------------------------------------------------------------
    dp = sub.add_parser(
        "demo", help="the paper's experiment: plan + smooth on paper-multi, Figs. 2-4 and a GIF",
        formatter_class=_Formatter,
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
    _common(dp, out_default="demo_out")
    dp.set_defaults(func=_cmd_demo)
    return p


# ------------------------------------------------------------- utilities
class _Run:
    """What a subcommand needs besides its arguments: output folder, messages."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.quiet = bool(getattr(args, "quiet", False))
        self.out: Path | None = getattr(args, "out", None)
        self.written: list[Path] = []

    def prepare_out(self) -> Path:
        out = self.out
        if out.exists() and not out.is_dir():
            raise ValidationError("--out", f"{out} exists and is not a folder")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValidationError("--out", f"cannot create folder {out}: {exc.strerror or exc}") from None
        return out

    def wrote(self, path: Path) -> Path:
        self.written.append(Path(path))
        log.debug("wrote %s", path)
        return Path(path)

    def say(self, text: str) -> None:
        """A result line on stdout (not with --quiet)."""
        if not self.quiet:
            print(text)

    def list_written(self) -> None:
        for p in self.written:
            self.say(f"wrote {p}")


def _load_scenario(spec: str, alpha: float | None):
    from .scenario import load_scenario

    sc = load_scenario(spec)
    if alpha is not None:
        sc = sc.with_options(alpha=alpha)
    return sc


def _fmt_alpha(a: float) -> str:
    return f"{a:g}"


def _load_input_path(file: Path):
    """A BeliefPath from a plan result, a belief path or a smoothing result file
    (JSON or NPZ). Returns (path, info dict)."""
    import numpy as np

    from .path import BeliefPath

    file = Path(file)
    if not file.is_file():
        raise ValidationError("--path", f"no such file: {file}")
    if file.suffix == ".npz":
        try:
            with np.load(file, allow_pickle=False) as z:
                names = set(z.files)
        except (OSError, ValueError) as exc:
            raise ValidationError("--path", f"{file}: not an NPZ file: {exc}") from None
        if "header" in names:
            return _path_of_plan(_plan_result_cls().load(file), file)
        return BeliefPath.load(file), {"source": str(file), "kind": "path"}
    try:
        data = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValidationError("--path", f"{file}: malformed JSON: {exc}") from None
    if isinstance(data, dict) and str(data.get("format", "")).startswith("belief_nlp.PlanResult"):
        return _path_of_plan(_plan_result_cls().from_dict(data), file)
    if isinstance(data, dict) and "path" in data and "x" not in data:
        if not isinstance(data["path"], dict):
            raise ValidationError("--path", f"{file}: the result holds no path")
        return BeliefPath.from_dict(data["path"]), {"source": str(file), "kind": "smooth result"}
    return BeliefPath.from_dict(data), {"source": str(file), "kind": "path"}


def _plan_result_cls():
    from .planner import PlanResult

    return PlanResult


def _path_of_plan(result, file: Path):
    if result.path is None:
        raise ValidationError("--path", f"{file}: the plan result holds no path ({result.message})")
    return result.path, {"source": str(file), "kind": "plan result", "scenario": result.scenario}


def _save_path(run: _Run, path, stem: str) -> Path:
    return run.wrote(path.save(run.out / f"{stem}.{run.args.format}"))


def _save_fig(run: _Run, fig, name: str) -> Path:
    import matplotlib.pyplot as plt

    from .plotting import save_figure

    try:
        return run.wrote(save_figure(fig, run.out / name, dpi=run.args.dpi))
    finally:
        plt.close(fig)


def _panels(n: int, dim: int, size: float = 4.6):
    """A figure with n scenario panels side by side (3-D axes for 3-D scenarios)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(size * n, size))
    kw = {"projection": "3d"} if dim == 3 else {}
    return fig, [fig.add_subplot(1, n, i + 1, **kw) for i in range(n)]


def _no_path_panel(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9, color="tab:red",
            zorder=20, bbox={"facecolor": "white", "edgecolor": "tab:red", "alpha": 0.85})


# --------------------------------------------------------------- planning
def _plan(run: _Run, sc, *, label: str = "", stem: str = "plan", figures: bool = True):
    """Plan with the args' planner options; write the result file (+ figures).
    Returns the PlanResult (successful or not)."""
    from .planner import plan

    a = run.args
    log.info("%splanning on %s with IG-RRT*: %d nodes, seed %d, alpha %g, %s noise", label, sc.name or "scenario",
             a.nodes, a.seed, sc.alpha, a.noise)
    t0 = time.perf_counter()
    extra = {} if a.max_radius is None else {"max_radius": a.max_radius}
    res = plan(sc, n_nodes=a.nodes, seed=a.seed, metric=a.metric, noise=a.noise, time_limit=a.time_limit,
               branch_and_bound=a.branch_and_bound, progress=not run.quiet, **extra)
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


def _plan_figures(run: _Run, sc, res, stem: str) -> None:
    from .plotting import plot_anytime, plot_belief_path, plot_scenario, plot_tree

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
    print(f"{PROG}: planning failed: {_one_line(res.message)} (try more --nodes, another --seed or a larger "
          f"--max-radius)", file=sys.stderr)
    return EXIT_FAILED


# -------------------------------------------------------------- smoothing
def _smooth(run: _Run, sc, path, method: str, *, keep_iterates: bool = False, label: str = ""):
    from .smoothing import smooth

    a = run.args
    K, why = _horizon(a.horizon, sc, path)
    log.info("%ssmoothing with %s: K = %d (%s), at most %d iterations", label, method.upper(), K, why,
             a.max_iter)
    t0 = time.perf_counter()
    try:
        res = smooth(sc, path, method=method, K=K, max_iter=a.max_iter, tol=a.tol, solver=a.solver,
                     time_limit=a.time_limit, keep_iterates=keep_iterates, progress=not run.quiet)
    except ImportError as exc:  # a method whose module is not installed
        raise BeliefNLPError(f"method {method!r} is not available in this installation: {exc}") from None
    log.info("%s%s: %s, cost %.6g after %d iterations in %.1f s", label, method.upper(), res.status, res.cost,
             res.nit, time.perf_counter() - t0)
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
    """Cost per iteration as drawn: CCP's accepted iterates (a rejected step is
    not part of the run); for IPOPT every iterate, feasible or not (its
    interior-point iterates become feasible only as it converges)."""
    keep_all = getattr(res, "method", "ccp") != "ccp"
    return [h.cost for h in res.history if (keep_all or h.accepted) and math.isfinite(h.cost)]


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


# -------------------------------------------------------------- commands
def _cmd_scenarios(run: _Run) -> int:
    from .scenario import list_scenarios, load_scenario, save_scenario

    a = run.args
    if a.name is None:
        if a.export or a.plot:
            raise ValidationError("name", "--export and --plot need a scenario NAME")
        for name in list_scenarios():
            sc = load_scenario(name)
            print(f"{name:12s} {sc.dim}-D, {len(sc.obstacles)} obstacles  {sc.description}")
        return EXIT_OK
    sc = load_scenario(a.name)
    if a.export is not None:
        save_scenario(sc, a.export)
        run.say(f"wrote {a.export}")
    if a.plot is not None:
        from .plotting import plot_scenario, save_figure
        import matplotlib.pyplot as plt

        fig, ax = plot_scenario(sc, annotate=True)
        ax.set_title(sc.name or str(a.name), fontsize=9)
        try:
            save_figure(fig, a.plot)
        finally:
            plt.close(fig)
        run.say(f"wrote {a.plot}")
    if a.export is None and a.plot is None:
        print(_describe_scenario(sc))
    return EXIT_OK


def _describe_scenario(sc) -> str:
    import numpy as np

    def arr(v) -> str:
        v = np.asarray(v, dtype=float)
        if v.ndim == 0:
            return f"{float(v):.4g}"
        return "[" + ", ".join(arr(row) for row in v) + "]"

    conf = (f"confidence {sc.confidence:g} (chi2 = {sc.chi2:.5g})" if sc.confidence is not None
            else f"chi2 = {sc.chi2:.5g}")
    lines = [f"{sc.name or 'scenario'}: {sc.description}" if sc.description else (sc.name or "scenario"),
             f"  dimension     {sc.dim}",
             f"  domain        {arr(sc.domain.bounding_box()[0])} .. {arr(sc.domain.bounding_box()[1])} "
             f"({sc.domain.A.shape[0]} faces)",
             f"  target        {arr(sc.target.bounding_box()[0])} .. {arr(sc.target.bounding_box()[1])} "
             f"({sc.target.A.shape[0]} faces)",
             f"  start         x0 = {arr(sc.x0)}, P0 = {arr(sc.P0)}",
             f"  noise         W = {arr(sc.W)} per step, W_rate = {arr(sc.W_rate)} per metre",
             f"  alpha         {sc.alpha:g}",
             f"  ellipses      {conf}",
             f"  horizon K     {sc.K if sc.K is not None else '(one step per path edge)'}",
             f"  planner       {sc.planner or '{}'}",
             f"  obstacles     {len(sc.obstacles)}"]
    for ob in sc.obstacles:
        lines.append(f"    {ob.name}: {ob.vertices.shape[0]} vertices, "
                     f"{arr(ob.vertices.min(axis=0))} .. {arr(ob.vertices.max(axis=0))}")
    return "\n".join(lines)


def _cmd_plan(run: _Run) -> int:
    a = run.args
    sc = _load_scenario(a.scenario, a.alpha)
    run.prepare_out()
    res = _plan(run, sc)
    run.list_written()
    if not res.success:
        return _plan_failed(res)
    run.say(f"plan: cost {res.cost:.6g} (length {res.travel:.4g} m + {res.alpha:g} x information "
            f"{res.information:.4g} {res.info_unit}), {res.path.K} steps, first solution at node "
            f"{res.first_solution_iteration}")
    return EXIT_OK


def _cmd_smooth(run: _Run) -> int:
    from .plotting import animate_smoothing, plot_belief_path, plot_cost_history

    a = run.args
    sc = _load_scenario(a.scenario, a.alpha)
    run.prepare_out()
    path, code = _obtain_path(run, sc)
    if path is None:
        run.list_written()
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
    note = "" if res.method == "ccp" else ", iterates feasible only near the end"
    ax.set_title(f"steering cost (alpha = {res.alpha:g}{note})", fontsize=9)
    _save_fig(run, fig, "smooth_cost.png")
    if a.gif and res.iterates:
        gif, _ = animate_smoothing(sc, res.iterates, run.out / "smoothing.gif", dpi=min(a.dpi, 80))
        run.wrote(gif)
    run.list_written()
    run.say(f"smooth: {_status_line(res)}; cost {res.initial_cost:.6g} -> {res.cost:.6g} "
            f"(control {res.control:.4g} + {res.alpha:g} x information {res.information:.4g} nats), "
            f"K = {res.path.K}, {res.nit} iterations")
    if _smooth_failed(res):
        print(f"{PROG}: smoothing failed: {_status_line(res)}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _cmd_compare(run: _Run) -> int:
    try:
        from .compare import compare, records_to_table
    except ImportError as exc:  # being built
        raise BeliefNLPError(f"the comparison module is not available in this installation ({exc})") from None
    a = run.args
    sc = _load_scenario(a.scenario, a.alpha)
    run.prepare_out()
    path, code = _obtain_path(run, sc)
    if path is None:
        run.list_written()
        return code
    log.info("comparing %s on %s", ", ".join(a.methods), sc.name or "scenario")
    K, why = _horizon(a.horizon, sc, path)
    log.info("K = %d (%s)", K, why)
    records = compare(sc, path, methods=tuple(a.methods), K=K, max_iter=a.max_iter, tol=a.tol,
                      solver=a.solver, time_limit=a.time_limit, progress=not run.quiet)
    table = records_to_table(records)
    (run.out / "compare.json").write_text(json.dumps(_jsonable(records), indent=1, allow_nan=True))
    run.wrote(run.out / "compare.json")
    (run.out / "compare.txt").write_text(table + "\n")
    run.wrote(run.out / "compare.txt")
    for rec in records:
        p = _record_path(rec)
        if p is not None:
            _save_path(run, p, f"compare_path_{rec.get('method')}")
    _compare_figures(run, sc, path, records)
    run.list_written()
    if not run.quiet:
        print(table)
    if records and all(_record_failed(r) for r in records):
        print(f"{PROG}: every method failed: " + "; ".join(
            f"{r.get('method')}: {r.get('status')}" for r in records), file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _record_failed(rec: dict) -> bool:
    return rec.get("status") in FAILED_STATUSES or rec.get("path") is None or rec.get("safe") is False


def _record_path(rec: dict):
    from .path import BeliefPath

    p = rec.get("path")
    if p is None or isinstance(p, BeliefPath):
        return p
    if isinstance(p, dict):
        return BeliefPath.from_dict(p)
    return None


def _compare_figures(run: _Run, sc, path, records: list[dict]) -> None:
    from .plotting import plot_belief_path, plot_cost_history

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
        if hist:  # CCP: accepted iterates; IPOPT: every iterate (feasible only near the end)
            histories[method] = [h["cost"] for h in hist if (method != "ccp" or h.get("accepted", True))
                                 and h.get("cost") is not None and math.isfinite(h["cost"])]
    _save_fig(run, fig, "compare.png")
    if histories:
        fig, ax = plot_cost_history(histories, xlabel="iteration (CCP: convex solves; IPOPT: Newton steps)",
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


def _cmd_demo(run: _Run) -> int:
    import numpy as np

    from .plotting import animate_smoothing, plot_belief_path, plot_cost_history, plot_scenario

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
        sc = base.with_options(alpha=alpha)
        tag = f"alpha{_fmt_alpha(alpha)}"
        label = f"[alpha = {_fmt_alpha(alpha)}] "
        entry: dict[str, Any] = {"alpha": alpha, "scenario": sc, "plan": None, "smooth": None}
        runs.append(entry)
        t0 = time.perf_counter()
        pres = _plan(run, sc, label=label, stem=f"plan_{tag}", figures=False)
        entry["plan"], entry["plan_time"] = pres, time.perf_counter() - t0
        if not pres.success:
            failures.append(f"alpha = {_fmt_alpha(alpha)}: planning failed: {pres.message}")
            continue
        t0 = time.perf_counter()
        try:
            sres = _smooth(run, sc, pres.path, "ccp", keep_iterates=a.gif, label=label)
        except BeliefNLPError as exc:
            if isinstance(exc, ValidationError):
                raise
            failures.append(f"alpha = {_fmt_alpha(alpha)}: smoothing failed: {exc}")
            entry["error"] = str(exc)
            continue
        entry["smooth"], entry["smooth_time"] = sres, time.perf_counter() - t0
        run.wrote(sres.save(run.out / f"smooth_{tag}.json"))
        _save_path(run, sres.path, f"smoothed_path_{tag}")
        if _smooth_failed(sres):
            failures.append(f"alpha = {_fmt_alpha(alpha)}: {_status_line(sres)}")
        if a.gif and sres.iterates:
            t0 = time.perf_counter()
            titles = [f"alpha = {_fmt_alpha(alpha)}, CCP iteration {i}: cost "
                      f"{p.steering_cost(alpha):.5g}" for i, p in enumerate(sres.iterates)]
            gif, _ = animate_smoothing(sc, sres.iterates, run.out / f"smoothing_{tag}.gif", fps=3,
                                       titles=titles, dpi=min(a.dpi, 80))
            run.wrote(gif)
            entry["gif_time"] = time.perf_counter() - t0

    # Fig. 2 and Fig. 3: planner paths and smoothed paths, one panel per alpha.
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

    # Fig. 4: steering cost against CCP iteration.
    histories = {f"alpha = {_fmt_alpha(e['alpha'])}": _accepted_costs(e["smooth"])
                 for e in runs if e["smooth"] is not None}
    fig, ax = plot_cost_history(histories or {"(no run)": []}, log=len(histories) > 1)
    ax.set_title("Fig. 4: steering cost vs CCP iteration", fontsize=10)
    _save_fig(run, fig, "fig4_cost_history.png")

    summary = {
        "scenario": base.name, "nodes": a.nodes, "seed": a.seed, "noise": a.noise, "metric": a.metric,
        "max_radius": a.max_radius,
        "max_iter": a.max_iter, "tol": a.tol, "horizon": a.horizon, "quick": a.quick,
        "W": np.asarray(base.W).tolist(), "total_time_s": time.perf_counter() - t_demo,
        "runs": [_run_summary(e) for e in runs], "failures": failures,
    }
    (run.out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True))
    run.wrote(run.out / "summary.json")
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
            print(f"{PROG}: {_one_line(f)}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


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


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


# ------------------------------------------------------------------ main
def _setup_logging(quiet: bool, verbose: int) -> Callable[[], None]:
    """Send belief_nlp's log to stderr for this run; returns the undo."""
    pkg = logging.getLogger("belief_nlp")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    saved = (pkg.level, log.level, pkg.propagate)
    if quiet:
        pkg_level, cli_level = logging.ERROR, logging.ERROR
    else:
        pkg_level = {0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG)
        cli_level = logging.DEBUG if verbose >= 2 else logging.INFO
    pkg.setLevel(pkg_level)
    log.setLevel(cli_level)
    pkg.addHandler(handler)
    pkg.propagate = False

    def undo() -> None:
        pkg.removeHandler(handler)
        pkg.setLevel(saved[0])
        log.setLevel(saved[1])
        pkg.propagate = saved[2]

    return undo


def _headless_matplotlib() -> None:
    """Draw off-screen unless the caller (a notebook, a script) already chose."""
    if "matplotlib.pyplot" not in sys.modules and not os.environ.get("MPLBACKEND"):
        import matplotlib

        matplotlib.use("Agg")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``belief-nlp`` with ``argv`` (default: ``sys.argv[1:]``); return the exit code.

    Never raises for bad input or failed runs: 0 success, 2 bad input (one line
    on stderr), 3 planning or solving failed.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(None if argv is None else list(argv))
    except _UsageError as exc:
        print(_one_line(exc), file=sys.stderr)
        return EXIT_BAD_INPUT
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0) if isinstance(exc.code, int) or exc.code is None else EXIT_BAD_INPUT
    _headless_matplotlib()
    undo = _setup_logging(args.quiet, args.verbose)
    run = _Run(args)
    try:
        return args.func(run)
    except ValidationError as exc:
        print(f"{PROG} {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BeliefNLPError as exc:
        print(f"{PROG} {args.command}: failed: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    except FileNotFoundError as exc:
        print(f"{PROG} {args.command}: error: no such file or folder: {exc.filename}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"{PROG} {args.command}: error: cannot write {exc.filename}: {exc.strerror}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        undo()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
