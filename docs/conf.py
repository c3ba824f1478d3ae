"""Sphinx configuration of bgap's documentation (Furo theme, MyST markdown).

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html``; the Python examples
run with ``sphinx-build -b doctest docs docs/_build/doctest``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))  # bgap_configref: the configuration reference
sys.path.insert(0, str(ROOT))  # bgap itself, also when it is not installed

# Plots drawn while the docs import bgap never need a display; numba's compiled kernels are
# cached beside the package as in any other run.
os.environ.setdefault("MPLBACKEND", "Agg")

project = "bgap"
author = "bgap contributors"
copyright = "2026, bgap contributors"
try:
    from importlib.metadata import version as _version

    release = _version("bgap")
except Exception:  # pragma: no cover - a source tree that was never installed
    release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.doctest",
    "bgap_configref",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]

# MyST: ::: fences, definition lists, and anchors for every heading down to level 3, so
# pages link to each other's sections as [text](page.md#section-slug).
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# autodoc: one automodule per module of the package, members in source order; type hints
# go into the description, where long ones stay readable.
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": True,
    "member-order": "bysource",
}
autodoc_typehints = "description"
autodoc_preserve_defaults = True
napoleon_google_docstring = True
napoleon_numpy_docstring = True

# doctest: only the docs' own {doctest} and {testcode} blocks run; the docstrings' usage
# sketches (which name files a reader has, not the build) are read, not run.
doctest_test_doctest_blocks = ""
doctest_global_setup = """
import os
import warnings

os.environ.setdefault("MPLBACKEND", "Agg")
warnings.filterwarnings("ignore", module="gymnasium")  # its env checker's notes on seeds
"""

html_theme = "furo"
html_title = "bgap"
html_static_path: list[str] = []
html_theme_options = {"navigation_with_keys": True}
