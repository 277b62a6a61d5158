"""Keep the notebooks' stored outputs in step with the code.

The notebooks in ``notebooks/`` are committed *with* their outputs (figures
included), so that they show their results where they are read (GitHub, the
documentation site, which renders them without running them). This script
re-executes each notebook in a fresh ``python3`` kernel, in a temporary
folder, with the full settings (``BELIEF_NLP_QUICK`` unset), and compares the
fresh outputs with the stored ones after normalising what legitimately
differs from run to run: wall-clock times, memory addresses and the bytes of
figures (a figure must still be there, with the same kinds of data).

Usage (from the repository root)::

    python tools/check_notebooks.py            # check every notebook; exit 1 on a difference
    python tools/check_notebooks.py --write    # re-execute and store the outputs
    python tools/check_notebooks.py 01_quickstart --write
    python tools/check_notebooks.py --jobs 2   # two notebooks at a time, each in its own process (CI)

Notebooks are found by globbing ``notebooks/*.ipynb``, so a new one is checked
without touching this file. A notebook may name modules it needs in its
metadata (``{"belief_nlp": {"requires": [...]}}``); it is skipped, with the
reason, when one is missing.
"""

from __future__ import annotations

import argparse
import difflib
import importlib.util
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOK_DIR = ROOT / "notebooks"
TIMEOUT = 1200  # s per cell; notebook 03 runs SQP, which takes tens of seconds

# Figures are stored small: PNG (the inline backend's default format) at a
# modest resolution, given to the kernel's matplotlib through a matplotlibrc
# file (MATPLOTLIBRC), so that the notebooks' code stays as a user runs it.
FIGURE_DPI = 60

# A number followed by a unit of time ("1.2 s", "35 ms", "0.4 s)", "12.0s").
_TIME = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?\s?(?:ms|us|µs|s|sec|seconds|min)(?![\w])")
_ADDRESS = re.compile(r"0x[0-9a-fA-F]{6,}")
_IMAGE_MIME = re.compile(r"^image/")


def notebooks(names: list[str] | None = None) -> list[Path]:
    """The notebooks to check: all of ``notebooks/*.ipynb``, or those whose stem is in ``names``."""
    found = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
    if not names:
        return found
    wanted = {Path(n).stem for n in names}
    unknown = wanted - {p.stem for p in found}
    if unknown:
        raise SystemExit(f"check_notebooks: no notebook named {', '.join(sorted(unknown))} in {NOTEBOOK_DIR}")
    return [p for p in found if p.stem in wanted]


def missing_requirements(nb: nbformat.NotebookNode) -> list[str]:
    """Modules the notebook's metadata requires that cannot be imported here."""
    required = nb.metadata.get("belief_nlp", {}).get("requires", [])
    out = []
    for name in required:
        try:
            if importlib.util.find_spec(name) is None:
                out.append(name)
        except ModuleNotFoundError:  # a parent package is missing
            out.append(name)
    return out


def execute(path: Path, quick: bool = False, timeout: int = TIMEOUT) -> nbformat.NotebookNode:
    """Run a copy of the notebook at ``path`` in a fresh kernel and return it with fresh outputs.

    The kernel runs in a temporary folder (notebooks write their figures and
    files next to themselves) with the environment of this process, less
    ``MPLBACKEND`` (the kernel uses its inline backend) and with
    ``BELIEF_NLP_QUICK`` set to ``"1"`` only when ``quick``.
    """
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    saved = {k: os.environ.get(k) for k in ("BELIEF_NLP_QUICK", "MPLBACKEND", "MATPLOTLIBRC")}
    os.environ.pop("MPLBACKEND", None)
    if quick:
        os.environ["BELIEF_NLP_QUICK"] = "1"
    else:
        os.environ.pop("BELIEF_NLP_QUICK", None)
    try:
        with tempfile.TemporaryDirectory() as folder:
            rc = Path(folder) / "matplotlibrc"
            rc.write_text(f"figure.dpi: {FIGURE_DPI}\n")
            os.environ["MATPLOTLIBRC"] = str(rc)
            km = _kernel_manager(folder)
            client = NotebookClient(nb, timeout=timeout, kernel_name="python3", record_timing=False,
                                    km=km, resources={"metadata": {"path": folder}})
            try:
                client.execute()
            finally:  # nbclient shuts down only the kernels of managers it made itself
                if km.has_kernel:
                    km.shutdown_kernel(now=True)
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
    return tidy(nb)


def _kernel_manager(folder: str):
    """A kernel manager whose kernel talks over Unix sockets in ``folder``.

    Over TCP, jupyter_client picks free ports, closes them and lets the kernel
    bind them later; with ``--jobs 2`` two kernels starting at once can pick
    the same port, and one dies before its first reply ("Kernel died before
    replying to kernel_info": a CI run lost notebook 02 that way). Socket
    files in a folder of this kernel's own cannot collide.
    """
    from jupyter_client.manager import KernelManager

    return KernelManager(kernel_name="python3", transport="ipc", ip=str(Path(folder) / "kernel"))


def tidy(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Drop what varies from machine to machine and carries no result: the
    kernel's version in the notebook metadata and per-cell execution records."""
    nb.metadata["language_info"] = {"name": "python"}
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
        if cell.cell_type == "code":
            for out in cell.get("outputs", []):
                out.get("metadata", {}).pop("execution", None)
    return nb


def _is_time_header(cell: str) -> bool:
    """A table column of timings: its header ends in a unit of time ("wall s", "solver ms", "time")."""
    words = cell.lower().split()
    return bool(words) and (words[-1] in ("s", "ms", "us", "sec", "seconds", "time") or "time" in words[-1])


def _normalise_tables(lines: list[str]) -> list[str]:
    """Markdown tables (``| a | b |`` rows, as ``records_to_table`` prints) with
    the cells of timing columns replaced and the padding of every cell removed
    (column widths follow the widest value, a timing included)."""
    out, timing = [], None
    for line in lines:
        stripped = line.strip()
        if not (stripped.startswith("|") and stripped.endswith("|")):
            out.append(line)
            timing = None
            continue
        cells = [c.strip() for c in stripped[1:-1].split("|")]
        if timing is None:  # the header row
            timing = [_is_time_header(c) for c in cells]
        elif not set("".join(cells)) <= set("-: "):
            cells = ["<time>" if i < len(timing) and timing[i] else c for i, c in enumerate(cells)]
        else:
            cells = ["---"] * len(cells)
        out.append("| " + " | ".join(cells) + " |")
    return out


def normalise_text(text: str) -> str:
    """Text with timings (numbers with a unit of time, timing columns of
    tables) and memory addresses replaced by placeholders."""
    text = _ADDRESS.sub("0x<address>", text)
    return "\n".join(_normalise_tables(_TIME.sub("<time>", text).splitlines()))


def _output_lines(out: dict) -> list[str]:
    kind = out.get("output_type")
    if kind == "stream":
        return [f"[{out.get('name')}]"] + normalise_text(out.get("text", "")).splitlines()
    if kind == "error":
        return [f"[error {out.get('ename')}: {normalise_text(out.get('evalue', ''))}]"]
    data = out.get("data", {})
    lines = [f"[{kind}: {', '.join(sorted(data))}]"]
    for mime in sorted(data):
        if _IMAGE_MIME.match(mime):
            continue  # a figure: its kind counts, not its bytes
        value = data[mime]
        lines += normalise_text(value if isinstance(value, str) else "".join(value)).splitlines()
    return lines


def _merged(outputs: list) -> list[dict]:
    """Consecutive stream outputs to the same stream joined: how a kernel
    splits a stream into messages depends on timing, not on the result."""
    merged: list[dict] = []
    for out in outputs:
        if (out.get("output_type") == "stream" and merged and merged[-1].get("output_type") == "stream"
                and merged[-1].get("name") == out.get("name")):
            merged[-1] = {**merged[-1], "text": merged[-1]["text"] + out.get("text", "")}
        else:
            merged.append(dict(out))
    return merged


def normalised(nb: nbformat.NotebookNode) -> list[str]:
    """The notebook as comparable lines: each code cell's source and its normalised outputs."""
    lines: list[str] = []
    for index, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        lines.append(f"--- cell {index}")
        for out in _merged(cell.get("outputs", [])):
            lines += _output_lines(out)
    return lines


def difference(stored: nbformat.NotebookNode, fresh: nbformat.NotebookNode, name: str = "notebook") -> str:
    """A unified diff of the normalised outputs ('' when they agree)."""
    if [c.source for c in stored.cells] != [c.source for c in fresh.cells]:
        return f"{name}: the cells differ (the stored notebook is not the one executed)"
    diff = difflib.unified_diff(normalised(stored), normalised(fresh), f"{name} (stored)", f"{name} (re-executed)",
                                lineterm="", n=1)
    return "\n".join(diff)


def missing_outputs(nb: nbformat.NotebookNode) -> list[int]:
    """Indices of code cells with no execution count: cells never executed before storing."""
    return [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and c.get("execution_count") is None]


def _timed_execute(path: Path) -> tuple[nbformat.NotebookNode | None, str | None, float]:
    """(fresh notebook, None, seconds), or (None, the failure's last line, seconds) when a cell raised."""
    start = time.perf_counter()
    try:
        fresh = execute(path)
    except Exception as exc:  # a cell raised: report it as this notebook's failure
        return None, str(exc).strip().splitlines()[-1], time.perf_counter() - start
    return fresh, None, time.perf_counter() - start


def _executed(paths: list[Path], jobs: int):
    """_timed_execute of each path, in the order given; ``jobs`` > 1 runs that
    many at a time, each in a process of its own (execute() sets environment
    variables for its kernel, so one process executes one notebook at a time)."""
    if jobs <= 1 or len(paths) <= 1:
        yield from map(_timed_execute, paths)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(min(jobs, len(paths)), mp_context=multiprocessing.get_context("spawn")) as pool:
        yield from pool.map(_timed_execute, paths)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="notebook stems (default: every notebook in notebooks/)")
    parser.add_argument("--write", action="store_true", help="store the fresh outputs instead of comparing")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="notebooks executed at a time, each in its own process (default 1)")
    args = parser.parse_args(argv)

    failed = []
    total = time.perf_counter()
    runnable = []
    for path in notebooks(args.names):
        stored = nbformat.read(path, as_version=4)
        missing = missing_requirements(stored)
        if missing:
            print(f"{path.name}: skipped, needs {', '.join(missing)}", flush=True)
            continue
        runnable.append((path, stored))
    for (path, stored), (fresh, error, seconds) in zip(runnable, _executed([p for p, _ in runnable], args.jobs)):
        if error is not None:
            print(f"{path.name}: execution failed: {error}", flush=True)
            failed.append(path.name)
            continue
        if args.write:
            nbformat.validate(fresh)
            nbformat.write(fresh, path)
            print(f"{path.name}: stored ({seconds:.1f} s, {path.stat().st_size / 1024:.0f} KiB)", flush=True)
            continue
        diff = difference(stored, fresh, path.name)
        never_run = missing_outputs(stored)
        if never_run:
            diff = f"{path.name}: cells {never_run} were stored without outputs\n" + diff
        if diff:
            print(diff, flush=True)
            failed.append(path.name)
        print(f"{path.name}: {'DIFFERS' if diff else 'ok'} ({seconds:.1f} s)", flush=True)
    print(f"{time.perf_counter() - total:.1f} s in all", flush=True)
    if failed:
        print(f"outputs out of step: {', '.join(failed)} (re-store with: python tools/check_notebooks.py --write)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
