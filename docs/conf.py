"""Sphinx configuration of the netsim documentation.

Why this stack (Sphinx + autodoc + numpydoc + sphinx-gallery): netsim's docstrings are
written in numpydoc style, which numpydoc renders without rewriting them; autodoc reads
the API reference from the code itself; sphinx-gallery runs the example scripts at build
time, so every figure in the gallery is made by the code it documents. python-control
and Stone Soup, the closest projects in the field, use the same stack, and all of it is
well kept and installs from PyPI without system packages. Math uses Sphinx's built-in
mathjax extension (rendered in the reader's browser; the build needs no network), the
layer diagram is a literal block (no graphviz ``dot`` binary needed), and intersphinx is
off, so a build never touches the network.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html``; doctests:
``sphinx-build -b doctest docs docs/_build/doctest``. ``NETSIM_DOCS_FULL=1`` also executes
the 100,000-agent gallery example (minutes from a cold gain cache).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

# The gallery scripts find the repository's examples/ through this variable.
os.environ.setdefault("NETSIM_REPO_ROOT", str(HERE.parent))
# Matplotlib without a display.
os.environ.setdefault("MPLBACKEND", "Agg")

import netsim  # noqa: E402

project = "netsim"
author = "the netsim authors"
copyright = "the netsim authors, MIT licence"  # noqa: A001
release = netsim.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.doctest",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "netsim_docs",
]

root_doc = "index"
exclude_patterns = ["_build", "gallery/GALLERY_HEADER.rst", "auto_examples/*.ipynb",
                    "auto_examples/*.py", "auto_examples/*.zip", "auto_examples/*.json",
                    "**.codeobj.json"]
templates_path: list[str] = []
nitpicky = False

html_theme = "alabaster"
html_static_path: list[str] = []
html_theme_options = {
    "description": "Distributed state estimation over networks with delays",
    "fixed_sidebar": True,
    "page_width": "1100px",
}
html_title = "netsim documentation"

# -- autodoc / numpydoc -----------------------------------------------------------------
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

# -- doctest ------------------------------------------------------------------------------
doctest_global_setup = """
import os, tempfile
os.chdir(tempfile.mkdtemp(prefix="netsim-doctest-"))
"""

# -- sphinx-gallery ---------------------------------------------------------------------
FULL = os.environ.get("NETSIM_DOCS_FULL", "") not in ("", "0")

sphinx_gallery_conf = {
    "examples_dirs": "gallery",
    "gallery_dirs": "auto_examples",
    # plot_geometric_100k.py is executed only with NETSIM_DOCS_FULL=1 (minutes).
    "filename_pattern": r"/plot_" if FULL else r"/plot_(?!geometric_100k)",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "show_memory": False,
    "write_computation_times": False,
    "image_scrapers": ("matplotlib",),
    "matplotlib_animations": False,
    "default_thumb_file": str(HERE / "foxglove-layout.png"),
}
smartquotes = False  # option names such as --engine stay as typed
