"""The ``belief-nlp`` command line.

Exit codes: 0 success, 2 bad input (one-line message, no traceback),
3 planning or solving failed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .errors import BeliefNLPError, ValidationError

EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED = 0, 2, 3


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from .scenario import list_scenarios, load_scenario, save_scenario

    if args.name is None:
        for name in list_scenarios():
            sc = load_scenario(name)
            print(f"{name:14s} d={sc.dim} obstacles={len(sc.obstacles)}  {sc.description}")
        return EXIT_OK
    sc = load_scenario(args.name)
    if args.export:
        save_scenario(sc, args.export)
        print(f"wrote {args.export}")
    else:
        print(repr(sc))
        print(sc.description)
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="belief-nlp", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    sp = sub.add_parser("scenarios", help="list built-in scenarios, show or export one")
    sp.add_argument("name", nargs="?", help="built-in name or scenario file")
    sp.add_argument("--export", type=Path, help="write the scenario to this .toml/.json file")
    sp.set_defaults(func=_cmd_scenarios)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValidationError as exc:
        print(f"belief-nlp: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BeliefNLPError as exc:
        print(f"belief-nlp: failed: {exc}", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
