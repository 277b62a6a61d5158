"""The notebooks: stored with their outputs, in step with the code, and they run.

Notebooks are committed with the outputs of a full run (figures included) so
that they show their results where they are read; ``tools/check_notebooks.py``
re-executes all of them and compares (CI runs it; ``--write`` re-stores).
Here, within the default suite's time:

* every stored notebook is complete, small, with small PNG figures and no
  execution timings;
* the normalised comparison itself is checked on a stored notebook;
* the cheapest notebook is re-executed with the full settings and compared
  with its stored outputs (the others: ``-m slow`` or the script);
* every other notebook is executed on small settings (``BELIEF_NLP_QUICK=1``).

A notebook may name the modules it needs in its metadata
(``{"belief_nlp": {"requires": [...]}}``); it is skipped, with the reason,
only when one of them is missing from the tree.
"""

from __future__ import annotations

import base64
import copy
import importlib.util
import os
import struct
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
pytest.importorskip("nbclient")

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("check_notebooks", ROOT / "tools" / "check_notebooks.py")
check = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("check_notebooks", check)
_spec.loader.exec_module(check)

NOTEBOOKS = check.notebooks()
EXPECTED = ("01_quickstart", "02_paper_experiment", "03_solver_comparison", "04_mpc_export", "05_mpc_closed_loop",
            "06_risk_allocation")
# Re-executed with the full settings in the default suite (8-30 s, by load);
# the others take 20-90 s each at full size.
CHEAP = ("04_mpc_export",)
MAX_NOTEBOOK_KIB = 400
MAX_IMAGE_KIB = 256


def _ids(paths):
    return [p.stem for p in paths]


def _skip_if_missing(nb, path):
    missing = check.missing_requirements(nb)
    if missing:
        pytest.skip(f"{path.name} needs {', '.join(missing)}, which is not in this tree yet")


def _png_dpi(data: bytes) -> float | None:
    """Horizontal resolution from a PNG's pHYs chunk (pixels per metre -> dpi), None without one."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos = 8
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"pHYs":
            ppm_x, _, unit = struct.unpack(">IIB", data[pos + 8:pos + 17])
            return ppm_x * 0.0254 if unit == 1 else None
        if kind == b"IDAT":
            return None
        pos += 12 + length
    return None


def test_the_notebooks_are_found():
    # found by globbing, so that a new notebook is checked without edits here
    assert set(EXPECTED) <= {p.stem for p in NOTEBOOKS}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_stored_with_outputs(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    assert nb.metadata.get("kernelspec", {}).get("name") == "python3"
    assert nb.metadata.get("language_info") == {"name": "python"}, "kernel versions left in the metadata"
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1)), \
        f"{path.name}: not executed top to bottom in one run (python tools/check_notebooks.py --write)"
    images = 0
    for i, cell in enumerate(nb.cells):
        assert "execution" not in cell.metadata, f"{path.name} cell {i} stores execution timings"
        for out in cell.get("outputs", []):
            assert out.output_type != "error", f"{path.name} cell {i} stored an error"
            for mime, value in out.get("data", {}).items():
                if not mime.startswith("image/"):
                    continue
                images += 1
                assert mime in ("image/png", "image/gif"), f"{path.name} cell {i}: {mime} figure"
                assert len(value) <= MAX_IMAGE_KIB * 1024, f"{path.name} cell {i}: a {len(value) // 1024} KiB image"
                if mime == "image/png":
                    dpi = _png_dpi(base64.b64decode(value))
                    assert dpi is not None and dpi <= check.FIGURE_DPI + 0.5, \
                        f"{path.name} cell {i}: figure stored at {dpi} dpi"
    assert images >= 1, f"{path.name} shows no figure"
    assert path.stat().st_size <= MAX_NOTEBOOK_KIB * 1024, f"{path.name} is {path.stat().st_size // 1024} KiB"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_reads_the_quick_switch(path):
    """Every notebook must shrink itself when the test suite asks."""
    assert "BELIEF_NLP_QUICK" in path.read_text()


def test_the_comparison_ignores_timings_and_catches_results():
    stored = nbformat.read(ROOT / "notebooks" / "03_solver_comparison.ipynb", as_version=4)
    table = next(o for c in stored.cells if c.cell_type == "code" for o in c.outputs
                 if o.output_type == "stream" and "| method" in o.text)
    header, rule, first = table.text.splitlines()[:3]
    cells = first.split("|")
    wall = [h.strip() for h in header.split("|")].index("wall s")
    cost = [h.strip() for h in header.split("|")].index("cost")

    def edited(column, value):
        nb = copy.deepcopy(stored)
        out = next(o for c in nb.cells if c.cell_type == "code" for o in c.outputs
                   if o.output_type == "stream" and "| method" in o.text)
        row = list(cells)
        row[column] = f" {value} "
        out.text = out.text.replace(first, "|".join(row))
        return nb

    assert check.difference(stored, copy.deepcopy(stored)) == ""
    assert check.difference(stored, edited(wall, "123.45")) == ""            # a timing column
    assert "2.5" in check.difference(stored, edited(cost, "2.5"))            # a result
    later = copy.deepcopy(stored)
    later.cells[-2].source += "\n# changed"
    assert "cells differ" in check.difference(stored, later)
    assert check.normalise_text("plan (seed 0, 1.3 s), 35 ms per step, 12 steps") == \
        "plan (seed 0, <time>), <time> per step, 12 steps"


# .ci/run executes every notebook in full and compares it with its stored
# outputs (tools/check_notebooks.py) before the suite, and then sets this: the
# suite's own executions would run the same notebooks a second time (~60 s).
CHECKED_IN_THIS_RUN = os.environ.get("BELIEF_NLP_NOTEBOOKS_CHECKED") == "1"
_ALREADY = pytest.mark.skipif(CHECKED_IN_THIS_RUN, reason="every notebook was executed in full and compared with "
                              "its stored outputs by tools/check_notebooks.py earlier in this CI run")


def _compare_with_a_fresh_run(path):
    stored = nbformat.read(path, as_version=4)
    _skip_if_missing(stored, path)
    fresh = check.execute(path)
    diff = check.difference(stored, fresh, path.name)
    assert not diff, f"stored outputs out of step (python tools/check_notebooks.py {path.stem} --write):\n{diff}"


CHEAP_PATHS = [p for p in NOTEBOOKS if p.stem in CHEAP]
OTHER_PATHS = [p for p in NOTEBOOKS if p.stem not in CHEAP]


@_ALREADY
@pytest.mark.parametrize("path", CHEAP_PATHS, ids=_ids(CHEAP_PATHS))
def test_stored_outputs_match_a_fresh_run(path):
    _compare_with_a_fresh_run(path)


@pytest.mark.slow
@pytest.mark.parametrize("path", OTHER_PATHS, ids=_ids(OTHER_PATHS))
def test_stored_outputs_match_a_fresh_run_slow(path):
    _compare_with_a_fresh_run(path)


@_ALREADY
@pytest.mark.parametrize("path", OTHER_PATHS, ids=_ids(OTHER_PATHS))
def test_notebook_executes_on_small_settings(path):
    nb = nbformat.read(path, as_version=4)
    _skip_if_missing(nb, path)
    fresh = check.execute(path, quick=True)
    errors = [out for cell in fresh.cells if cell.cell_type == "code" for out in cell.outputs
              if out.get("output_type") == "error"]
    assert not errors


def test_stored_outputs_hold_no_machine_paths():
    """A stored output naming this machine's files (a warning's site-packages
    path) differs on every other machine: none may be stored (do-mpc's and
    CasADi's warnings are handled in belief_nlp.export.dompc)."""
    import json
    import re
    from pathlib import Path

    for nb in sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb")):
        for cell in json.loads(nb.read_text())["cells"]:
            for out in cell.get("outputs", []):
                text = "".join(out.get("text", [])) + "".join(out.get("data", {}).get("text/plain", []))
                assert not re.search(r"site-packages|/home/|/work/|/tmp/", text), (nb.name, text[:200])
