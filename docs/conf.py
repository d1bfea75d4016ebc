"""Sphinx configuration of the axialmix documentation site.

Build from the repository root (``pip install -e ".[docs]"``)::

    sphinx-build -W --keep-going -b html docs docs/_build/html

Pages are Markdown (myst-parser): the README, the science (MODELS.md) and an API reference
generated from the docstrings (autodoc). The notebooks in ``notebooks/`` (linked into this
folder as ``docs/notebooks``) are executed at build time by myst-nb at the size the test
suite runs them (``AXIALMIX_FULL=1`` builds them at full size); their figures are shown
inline. ``-W`` turns every warning, a failing notebook cell included, into an error.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import axialmix  # noqa: E402

project = "axialmix"
author = "axialmix developers"
copyright = "axialmix developers"
release = version = axialmix.__version__

extensions = [
    "myst_nb",  # Markdown (myst-parser) and notebooks
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]

source_suffix = {".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "notebooks/figures", "**/.ipynb_checkpoints"]
root_doc = "index"

# --- Markdown ------------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# --- notebooks: executed on every build, a failing cell fails the build ----------------------
nb_execution_mode = "force"
nb_execution_timeout = 900
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_merge_streams = True
# Figures the notebooks also save as files go to a scratch folder, not into the repository.
os.environ.setdefault("AXIALMIX_FIGURE_DIR", tempfile.mkdtemp(prefix="axialmix-docs-"))
os.environ.pop("MPLBACKEND", None)  # the kernel's inline backend shows the figures

# --- API reference ----------------------------------------------------------------------------
autodoc_default_options = {"members": True, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the docstrings state types and units in words
autodoc_preserve_defaults = True
napoleon_google_docstring = False
napoleon_numpy_docstring = False

# --- HTML -------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"axialmix {release}"
