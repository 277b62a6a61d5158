"""Sphinx configuration of the belief_nlp documentation site.

Build (from the repository root; the README gives the same line)::

    sphinx-build -W --keep-going -b html docs docs/_build/html

The Markdown guides in this folder are read by MyST (myst-nb), the API
reference comes from the docstrings (autodoc + autosummary, numpydoc style),
the CLI reference from the real argument parser (sphinx-argparse), and the
notebooks in ``notebooks/`` are rendered with the outputs stored in them:
the build never executes them (``python tools/check_notebooks.py`` keeps the
stored outputs in step with the code).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# Document the tree the build runs in, whatever is installed.
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

import belief_nlp  # noqa: E402

project = "belief_nlp"
author = "the belief_nlp authors"
copyright = "the belief_nlp authors, MIT licence"
release = version = belief_nlp.__version__

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinxarg.ext",
]

# -- sources ---------------------------------------------------------------
# The notebooks live in notebooks/ (outside this folder); each build copies
# them into _notebooks/ (git-ignored), so a new notebook appears by itself.
NOTEBOOK_COPIES = DOCS / "_notebooks"
shutil.rmtree(NOTEBOOK_COPIES, ignore_errors=True)
NOTEBOOK_COPIES.mkdir()
for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):
    shutil.copy2(notebook, NOTEBOOK_COPIES / notebook.name)

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints"]
templates_path = ["_templates"]
root_doc = "index"



def _write_statuses_table() -> None:
    """The table of smoothing statuses the reference includes, from the code itself."""
    from belief_nlp.smoother.result import STATUSES

    rows = "".join(f"   * - ``{name!r}``\n     - {meaning}\n" for name, meaning in STATUSES.items())
    target = DOCS / "api" / "generated" / "statuses.txt"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(".. list-table::\n   :header-rows: 1\n\n   * - status\n     - meaning\n" + rows)


_write_statuses_table()


def _names(values) -> str:
    return ", ".join(f"``{v}``" for v in values)


# Values the reference states, read from the code so that they never drift.
from belief_nlp.export import TOOLS  # noqa: E402
from belief_nlp.study import TIMING_COLUMNS  # noqa: E402

rst_epilog = (f".. |tools| replace:: {_names(TOOLS)}\n"
              f".. |timing_columns| replace:: {_names(TIMING_COLUMNS)}\n")

# -- MyST / myst-nb ----------------------------------------------------------
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3
nb_execution_mode = "off"          # stored outputs only; see the module docstring
nb_merge_streams = True
# notebook 02 shows its animation as a GIF
nb_mime_priority_overrides = [("html", "image/gif", 15)]

# -- API reference -----------------------------------------------------------
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"          # the signatures show them; numpydoc sections say the rest
autodoc_preserve_defaults = True
numpydoc_show_class_members = False  # the class template lists members itself
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False
nitpicky = False
# "--option" in the CLI reference and the guides stays two hyphens (no en dash)
smartquotes_action = "qe"

# -- HTML ------------------------------------------------------------------------
html_theme = "furo"
html_title = f"belief_nlp {release}"
html_static_path: list[str] = []
