"""The argparse machinery of ``belief-nlp``: a parser whose errors become one
line, the help formatter, checked value types, and the option groups that
several subcommands share. Each subcommand adds its own parser (``add_parser``
in its module); :func:`belief_nlp.cli.build_parser` puts them together."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .common import DEFAULT_METHOD, smoothing_methods


class _UsageError(Exception):
    """Raised instead of argparse's print-usage-and-exit, so main() can report one line."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors become one-line messages (exit code 2),
    with :class:`_Formatter` unless told otherwise."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

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


def _risk_budget(text: str) -> float:
    """An end-to-end collision budget, checked by RiskBudget (0 < Delta < 0.5)."""
    from ..allocation import RiskBudget
    from ..errors import ValidationError

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    try:
        return RiskBudget(value).budget
    except ValidationError:
        raise argparse.ArgumentTypeError(f"must be a number strictly between 0 and 0.5 (an end-to-end collision "
                                         f"probability), got {text!r}") from None


def _nonneg_float(text: str) -> float:
    return _number(text, positive=False)


# ------------------------------------------ option groups of several subcommands
def _output_args(p: argparse.ArgumentParser, out_default: str | None = "out") -> None:
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
                  max_radius: float | None = None, max_radius_help: str | None = None) -> None:
    """The planner's options; ``--max-radius`` defaults to ``max_radius``
    (None: the scenario's), explained by ``max_radius_help`` if given."""
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
                       " (default: the scenario's [planner] value)" if max_radius is None
                       else f" (default %(default)s: {max_radius_help})" if max_radius_help else "")
                   + ". With per_step noise every edge pays for a full W, so a larger cap than the "
                     "per-metre one lets IG-RRT* connect at large alpha")
    g.add_argument("--no-branch-and-bound", dest="branch_and_bound", action="store_false",
                   help="do not prune nodes that cannot beat the best path")
    g.add_argument("--backend", choices=("auto", "numpy", "numba"), default="auto",
                   help="how a 2-D sampling attempt runs: numba (compiled; the 'fast' extra; about 12 s of "
                        "compilation once per machine), numpy (the reference), auto (numba when installed)")


def _smoother_args(p: argparse.ArgumentParser, max_iter: int | None = None, method: bool = True,
                   path: bool = False, max_iter_help: str | None = None) -> None:
    """The smoother's options; ``--max-iter`` defaults to ``max_iter`` (None:
    each method's own limit), explained by ``max_iter_help`` if given."""
    if path:
        p.add_argument("--path", type=Path, metavar="FILE",
                       help="the path to smooth: a plan result, belief path or smoothing result (.json/.npz); "
                            "without it, plan first")
    p.add_argument("--time-limit", type=_positive_float, default=None, metavar="SECONDS",
                   help="wall-time limit of each planning and each smoothing run (the best feasible path "
                        "found is kept)")
    g = p.add_argument_group("smoother")
    if method:
        names = smoothing_methods()
        by_lower = {m.lower(): m for m in names}
        g.add_argument("--method", choices=names, default=DEFAULT_METHOD,
                       type=lambda v: by_lower.get(v.lower(), v),           # case-insensitive, as solver names
                       help="a registered smoothing method (belief-nlp methods lists them); auto: IPOPT on "
                            "the exact NLP, then CCP from the best safe point when IPOPT's answer is not "
                            "taken; ccp: the convex-concave procedure (the paper's), every iterate feasible; "
                            "ipopt: the exact NLP by IPOPT alone")
    g.add_argument("--horizon", "-K", dest="horizon", type=_positive_int, default=None, metavar="K",
                   help="time steps of the smoothed path, at least the path's edge count (edges are cut into "
                        "equal steps); default: the scenario's [horizon] K if the path fits, else one step "
                        "per edge")
    g.add_argument("--solver", default=None,
                   help="the method's solver; CCP: any installed CVXPY solver with PSD and exponential cones "
                        "(default CLARABEL, e.g. SCS); auto and ipopt: IPOPT")
    if max_iter_help is None and max_iter is None:
        max_iter_help = "default: each method's own, see belief-nlp methods"
    g.add_argument("--max-iter", type=_positive_int, default=max_iter,
                   help="iteration limit of the smoother" + (f" ({max_iter_help})" if max_iter_help else ""))
    g.add_argument("--tol", type=_positive_float, default=1e-4,
                   help="stop when an iteration lowers the cost by less than this fraction")


def _risk_args(p: argparse.ArgumentParser, allocation: bool = False) -> None:
    """``--risk`` (and, for the smoother, ``--allocation``): an end-to-end
    collision-probability budget instead of one fixed level for collisions."""
    from ..allocation import ALLOCATIONS, RISK_KINDS

    g = p.add_argument_group("risk budget")
    g.add_argument("--risk", type=_risk_budget, default=None, metavar="DELTA",
                   help="end-to-end collision-probability budget in (0, 0.5): the certified bound on a "
                        "collision at the step times stays within DELTA (the planner raises its collision "
                        "level until its path's bound fits); the scenario's confidence is then the target's "
                        "level only. Default: the scenario file's risk, if any")
    if allocation:
        g.add_argument("--allocation", choices=ALLOCATIONS, default=None,
                       help="how the smoother spends the budget over the transition-hazard pairs: optimal "
                            "(per-pair levels as decision variables, the default) or uniform (DELTA split "
                            "equally); needs a budget")
        g.add_argument("--risk-kind", choices=RISK_KINDS, default=None,
                       help="what the smoother's budget bounds: steps (being inside a hazard at a step time, the "
                            "default) or continuous (touching one at any instant, with feedback on the "
                            "estimate; through a per-pair surrogate, costlier paths); needs a budget")


def _plan_unless_path_args(p: argparse.ArgumentParser) -> None:
    """The planner and output options of a command that smooths --path, or
    plans first without it (smooth, compare)."""
    _planner_args(p, title="planner (only without --path)")
    _output_args(p)
