"""``belief-nlp cache``: show or clear the disk cache of compiled problems."""

from __future__ import annotations

from pathlib import Path

from ..errors import ValidationError
from .common import EXIT_FAILED, EXIT_OK, _Run
from .parser import _output_args


def add_parser(sub) -> None:
    """Add the ``cache`` subcommand to the subparsers ``sub``."""
    cp = sub.add_parser(
        "cache", help="show or clear the disk cache of compiled problems",
        description="The disk cache keeps what a process builds for a (scenario, K) -- the NLP graph, IPOPT's "
                    "derivative functions (with BELIEF_NLP_CACHE_COMPILE=1 also compiled: kinds 'lib' and 'cso'), the "
                    "CCP step's data -- for later processes. It is off unless "
                    "BELIEF_NLP_CACHE_DIR is set (a folder, or 1 for the user's cache folder) or a program calls "
                    "belief_nlp.set_disk_cache. Without --dir this shows the folder BELIEF_NLP_CACHE_DIR names, "
                    "else the user's cache folder: its entries by kind and size; --clear deletes them; --compile "
                    "builds the C library of every derivative entry that has none, in this process (the system C "
                    "compiler; e.g. when preparing a deployment image).",
        epilog="Examples:\n  belief-nlp cache\n  belief-nlp cache --dir /scratch/bn_cache --clear\n"
               "  belief-nlp cache --dir /opt/robot/bn_cache --compile")
    cp.add_argument("--dir", type=Path, default=None, metavar="DIR", help="the cache folder to show or clear")
    cp.add_argument("--clear", action="store_true", help="delete every entry (the signing key stays)")
    cp.add_argument("--compile", action="store_true",
                    help="compile the derivative functions of every entry that has no library yet")
    _output_args(cp, out_default=None)
    cp.set_defaults(func=_cmd_cache)


def _cmd_cache(run: _Run) -> int:
    from ..model.cache import DiskCache, compile_enabled, disk_cache

    a = run.args
    if a.dir is not None:
        disk, state = DiskCache(a.dir), "given by --dir"
    elif disk_cache() is not None:
        disk = disk_cache()
        state = "on (BELIEF_NLP_CACHE_DIR" + (", compiling: BELIEF_NLP_CACHE_COMPILE)" if compile_enabled() else ")")
    else:
        disk, state = DiskCache(), "off in this environment (BELIEF_NLP_CACHE_DIR unset)"
    if a.clear and a.compile:
        raise ValidationError("--compile", "cannot be combined with --clear")
    if a.clear:
        n, size = disk.clear()
        print(f"{disk.dir}: deleted {n} entries ({size / 2**20:.1f} MB)")
        return EXIT_OK
    if a.compile:
        from ..methods import nlp_compiled

        if nlp_compiled.compiler() is None:
            raise ValidationError("--compile", "no C compiler found (set CC, or install cc / gcc)")
        built, failed = nlp_compiled.compile_all(disk, progress=not run.quiet)
        print(f"{disk.dir}: compiled {built} entries" + (f", {len(failed)} failed: {', '.join(failed)}" if failed else ""))
        return EXIT_OK if not failed else EXIT_FAILED
    summary = disk.summary()
    total = sum(size for _, size in summary.values())
    print(f"{disk.dir}: {sum(n for n, _ in summary.values())} entries, {total / 2**20:.1f} MB "
          f"(cap {disk.max_bytes / 2**20:.0f} MB); disk cache {state}")
    for kind, (n, size) in sorted(summary.items()):
        print(f"  {kind:8s} {n:5d} entries {size / 2**20:8.1f} MB")
    return EXIT_OK
