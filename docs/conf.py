"""Sphinx configuration of the o3d_ofp documentation (``sphinx-build -W docs docs/_build/html``).

The site is built offline (CI reaches package registries only), so references to NumPy, SciPy,
Open3D, Dask and the standard library are resolved by ``_ext/offline_xref.py``: a name that
imports resolves to its page on the project's site; one that does not stays a broken reference
and fails the strict build, as a broken intersphinx reference would.
"""

from __future__ import annotations

import os
import sys
from datetime import date
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

import o3d_ofp  # noqa: E402

project = "o3d_ofp"
author = "o3d_ofp developers"
copyright = f"{date.today().year}, {author}"
release = o3d_ofp.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
    "offline_xref",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
# examples/ is the gallery's source (sphinx-gallery makes the pages in auto_examples/).
exclude_patterns = ["_build", "_templates", "examples", "auto_examples/*.ipynb", "**/*.zip"]
nitpicky = True
# Type words of numpydoc's parameter lines that are prose, not Python objects.
nitpick_ignore_regex = [("py:class", r"(array_like|array|optional|callable|path-like|scalar)")]

# API pages: one per public name, generated from the docstrings.
autosummary_generate = True
autosummary_imported_members = True
autodoc_typehints = "none"  # the numpydoc sections carry the types, with shapes
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# Gallery: every example runs when the docs build (headless: Open3D over EGL in a subprocess)
# and its pictures are matplotlib figures; each page offers the example as a notebook.
os.environ.setdefault("MPLBACKEND", "Agg")
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "image_scrapers": ("matplotlib",),
    "show_memory": False,
    "plot_gallery": "True",
}

html_theme = "pydata_sphinx_theme"
html_title = f"o3d_ofp {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
