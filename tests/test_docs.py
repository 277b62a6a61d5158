"""The documentation site builds with warnings as errors, and has what it promises.

Runs the README's docs-build command (``sphinx-build -W --keep-going``) into a
temporary folder when the ``docs`` extra is installed (the ``test`` extra
pulls it in, so CI builds the site); skipped, with the reason, without it.
The build renders the notebooks' stored outputs and never executes them.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS_PACKAGES = ("sphinx", "furo", "myst_nb", "numpydoc", "sphinxarg")
MISSING = [m for m in DOCS_PACKAGES if importlib.util.find_spec(m) is None]

pytestmark = pytest.mark.skipif(bool(MISSING), reason=f"the docs extra is not installed (no {', '.join(MISSING)})")


def _text(page: Path) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page.read_text()))


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(out / "doctrees"), "docs", str(out / "html")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"sphinx-build failed:\n{proc.stderr[-6000:]}"
    return out / "html"


def test_the_guides_are_pages(site):
    for guide in sorted((ROOT / "docs").glob("*.md")):
        assert (site / f"{guide.stem}.html").is_file(), f"docs/{guide.name} has no page"
    # the guides' links to each other still work on the site
    assert 'href="numerics.html"' in (site / "architecture.html").read_text()


def test_every_notebook_is_rendered_with_its_figures(site):
    import nbformat

    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        page = site / "_notebooks" / f"{path.stem}.html"
        assert page.is_file(), f"{path.name} is not on the site"
        nb = nbformat.read(path, as_version=4)
        figures = sum(1 for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
                      if any(m.startswith("image/") for m in o.get("data", {})))
        assert page.read_text().count("<img") >= figures >= 1


def test_the_api_reference_documents_the_top_level_names(site):
    import belief_nlp

    for name in belief_nlp.__all__:
        if name in ("DEFAULT_METHOD", "STATUSES"):
            assert f'id="belief_nlp.{name}"' in (site / "api" / "core.html").read_text()
        elif name in ("belief", "geometry"):
            assert (site / "api" / f"{name}.html").is_file()
        else:
            assert (site / "api" / "generated" / f"belief_nlp.{name}.html").is_file(), name
    smooth = _text(site / "api" / "generated" / "belief_nlp.smooth.html")
    assert "Parameters" in smooth and "Returns" in smooth and "k_fallback" in smooth
    # the statuses table is read from the code
    from belief_nlp.smoother.result import STATUSES

    core = _text(site / "api" / "core.html")
    assert all(status in core for status in STATUSES)


def test_the_cli_reference_comes_from_the_parser(site):
    from belief_nlp.cli import build_parser

    page = _text(site / "cli.html")
    import argparse

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert len(commands) >= 6
    for command in commands:
        assert f"belief-nlp {command}" in page, command
    assert "--max-radius" in page and "--horizon" in page   # options, with their two hyphens
