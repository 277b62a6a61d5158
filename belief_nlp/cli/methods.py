"""``belief-nlp methods``: list the registered smoothing methods and their options."""

from __future__ import annotations

from .common import EXIT_OK, _Run
from .parser import _output_args


def add_parser(sub) -> None:
    """Add the ``methods`` subcommand to the subparsers ``sub``."""
    mp = sub.add_parser(
        "methods", help="list the smoothing methods (built-in and registered) and their options",
        description="List every registered smoothing method, the default (used without --method) first: its "
                    "name (for --method / --methods), default iteration limit and what one iteration is, its "
                    "default solver, and its options (keywords of belief_nlp.smooth).",
        epilog="Example:\n  belief-nlp methods")
    _output_args(mp, out_default=None)
    mp.set_defaults(func=_cmd_methods)


def _cmd_methods(run: _Run) -> int:
    from ..smoother import DEFAULT_METHOD, available_methods, get_method

    for name in available_methods():
        m = get_method(name)
        solver = f", solver {m.default_solver}" if m.default_solver else ""
        default = " (the default)" if name == DEFAULT_METHOD else ""
        print(f"{name:14s} {m.description}{default}")
        print(f"{'':14s} max_iter {m.max_iter} ({m.iteration}){solver}")
        for opt, spec in m.options.items():
            if opt.startswith("_"):
                continue
            print(f"{'':14s}   {opt} = {spec.default!r}: {spec.doc}")
    return EXIT_OK
