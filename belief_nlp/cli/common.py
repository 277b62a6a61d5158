"""What every subcommand shares: exit codes, the smoothing method names, the
:class:`_Run` object, loading and saving helpers, logging setup and
one-line messages."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Callable

from ..errors import ValidationError
from ..smoother.registry import DEFAULT_METHOD  # noqa: F401 - the CLI's --method default

EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERNAL = 0, 2, 3, 1

#: Smoother statuses reported as failures (exit code 3). The others --
#: converged, max_iter, time_limit, non_monotone, infeasible_iterate -- end
#: with a verified path that the user asked for (an iteration or time budget)
#: or the best iterate before a rejected step, and exit 0 with the status shown.
FAILED_STATUSES = ("solver_failed", "ipopt_failed", "above_start")

PROG = "belief-nlp"

log = logging.getLogger("belief_nlp.cli")


# ------------------------------------------------------- smoothing methods
#: The paper's method, the convex-concave procedure: the one whose iterates are
#: all feasible and whose iteration count the paper's 15 (demo) refers to.
#: The default of ``--method`` is :data:`DEFAULT_METHOD` ("auto").
PAPER_METHOD = "ccp"


def smoothing_methods() -> tuple[str, ...]:
    """The smoothing methods the command line offers (``--method``, ``--methods``):
    the registry's, so a newly registered method needs no CLI edit."""
    from ..smoother import available_methods

    return tuple(available_methods())


def iterates_feasible(method: str) -> bool:
    """Whether every iterate a method reports is a feasible path: plain CCP's
    are (a rejected step is not part of the run); IPOPT's interior-point
    iterates become feasible only as it converges, and an auto run
    ("auto:ipopt", "auto:ccp", ...) starts with IPOPT's."""
    return method == PAPER_METHOD


# -------------------------------------------------------------- the run
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

    def write_text(self, name: str, text: str) -> Path:
        """Write OUT/name and record it."""
        path = self.out / name
        path.write_text(text)
        return self.wrote(path)

    def say(self, text: str) -> None:
        """A result line on stdout (not with --quiet)."""
        if not self.quiet:
            print(text)

    def list_written(self) -> None:
        for p in self.written:
            self.say(f"wrote {p}")


# ------------------------------------------------------- loading and saving
def _load_scenario(spec: str, alpha: float | None, risk: float | None = None):
    """The scenario with --alpha and --risk applied (a budget the start
    belief already spends is refused here, naming ``risk``)."""
    from ..scenario import load_scenario

    sc = load_scenario(spec)
    if alpha is not None:
        sc = sc.with_options(alpha=alpha)
    if risk is not None:
        sc = sc.with_options(risk=risk)
    return sc


def _fmt_alpha(a: float) -> str:
    return f"{a:g}"


def _load_input_path(file: Path):
    """A BeliefPath from a plan result, a belief path or a smoothing result file
    (JSON or NPZ). Returns (path, info dict); bad files name ``--path``."""
    from ..inputs import load_path_file

    return load_path_file(file, "--path")


def _save_path(run: _Run, path, stem: str) -> Path:
    return run.wrote(path.save(run.out / f"{stem}.{run.args.format}"))


# ---------------------------------------------------------------- messages
def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def _fail(message: str) -> int:
    """Report a failed run on one line of stderr; returns the exit code."""
    print(f"{PROG}: {message}", file=sys.stderr)
    return EXIT_FAILED


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
