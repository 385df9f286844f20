"""Sphinx configuration of opalflow's documentation (``sphinx-build -W docs docs/_build``; tests/test_docs.py)."""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE / "_ext"), str(HERE.parent)]

from opalflow.version import __version__  # noqa: E402

project = "opalflow"
author = "the opalflow developers"
release = version = __version__
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "opalflow_reference"]
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build", "figures/README.md"]
myst_heading_anchors = 3
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_numpy_docstring = True
html_theme = "alabaster"
html_static_path = []
suppress_warnings = ["myst.header"]
