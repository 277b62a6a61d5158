"""The belief-nlp command line: plan, smooth, compare and reproduce the paper.

Minimum-sensing path planning in Gaussian belief space:

  scenarios  list the built-in scenarios, show one, export it or draw it
  plan       run IG-RRT* and write the plan (JSON/NPZ) and its figures
  smooth     smooth a path (auto, CCP or IPOPT) read from a file, or plan first
  compare    smooth the same path with several methods and tabulate them
  methods    list the registered smoothing methods and their options
  demo       the paper's experiment on paper-multi: Figs. 2-4 and GIFs
  study      run a solver-comparison study (process pool or Dask), report or export it
  mpc        run a receding-horizon belief MPC (casadi.Opti, do-mpc or rockit)
  cache      show or clear the disk cache of compiled problems

Every subcommand takes ``--help``. Scenarios are built-in names (see
``belief-nlp scenarios``) or TOML/JSON files (docs/scenario_schema.md).

Exit codes: 0 success; 2 bad input (the reason on one line of stderr, no
traceback: unknown options, bad values, missing or malformed files); 3
planning or solving failed (the status on stderr; files written so far stay);
1 an internal error (a bug: one line, ``-v`` for the traceback).

Progress (tqdm bars and log lines) goes to stderr, results to stdout;
``--quiet`` silences both but for errors, ``-v`` shows the solvers' logs.

The package, one file per concern: ``parser`` (argparse machinery, value
types, shared option groups), ``common`` (exit codes, the smoothing method
names, the run object, loading and saving, logging, one-line messages),
``figures`` (shared figure helpers), and one module per subcommand --
``scenarios``, ``plan``, ``smooth``, ``compare``, ``methods``, ``demo``, ``study``, ``mpc``,
``cache`` -- each with its
``add_parser`` and its command.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ..errors import BeliefNLPError, ValidationError
from . import cache, compare, demo, methods, mpc, plan, scenarios, smooth, study
from .common import (EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERNAL, EXIT_OK, FAILED_STATUSES, PROG, _one_line,
                     _Run, _setup_logging, smoothing_methods)  # noqa: F401 - smoothing_methods: public
from .demo import DEMO_MAX_RADIUS  # noqa: F401 - public, as before the split
from .figures import _headless_matplotlib
from .parser import _Parser, _UsageError

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERNAL", "FAILED_STATUSES"]

#: The subcommands, in the order ``belief-nlp --help`` lists them.
_COMMANDS = (scenarios, plan, smooth, compare, methods, demo, study, mpc, cache)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``belief-nlp`` (errors raise instead of exiting)."""
    p = _Parser(prog=PROG, description=__doc__.split("Every subcommand")[0].strip(),
        epilog="Exit codes: 0 success, 2 bad input, 3 planning or solving failed, 1 internal error.\n\n"
               "Start with:\n  belief-nlp demo --out demo_out\n  belief-nlp COMMAND --help")
    from .._version import __version__

    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for command in _COMMANDS:
        command.add_parser(sub)
    return p


def _bars_and_logs():
    """On a terminal, log lines (-v) are written through tqdm so that they do
    not break a live progress bar; elsewhere there are no bars to break."""
    from contextlib import nullcontext

    from .._progress import _interactive

    if not _interactive():
        return nullcontext()
    import logging

    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm(loggers=[logging.getLogger("belief_nlp")])


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``belief-nlp`` with ``argv`` (default: ``sys.argv[1:]``); return the exit code.

    Never raises for bad input or failed runs: 0 success, 2 bad input (one line
    on stderr), 3 planning or solving failed, 1 an internal error (one line;
    the traceback with -v).
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
        with _bars_and_logs():
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
    except Exception as exc:  # noqa: BLE001 - a bug of ours: one line, the traceback only with -v
        if getattr(args, "verbose", 0):
            import traceback

            traceback.print_exc()
        print(f"{PROG} {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
              f"(rerun with -v for the traceback, and please report it)", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        undo()
