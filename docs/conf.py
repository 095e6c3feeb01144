"""Sphinx configuration of the o3d_ofp documentation (``sphinx-build -W docs docs/_build/html``).

The site is built offline (CI reaches package registries only), so references to NumPy, SciPy,
Open3D, Dask and the standard library are resolved by ``_ext/offline_xref.py``: a name that
imports resolves to its page on the project's site; one that does not stays a broken reference
and fails the strict build, as a broken intersphinx reference would.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import sys
from datetime import date
from pathlib import Path

from sphinx.pycode import ModuleAnalyzer

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
# Parameter and return types link to their classes (checked like every other reference); words
# of the type lines that are not below (shapes, "optional", "of") stay plain text. The defaults'
# Python and NumPy entries use intersphinx roles, replaced here by names offline_xref resolves.
numpydoc_xref_param_type = True
numpydoc_xref_ignore = "all"
numpydoc_xref_aliases = {
    **{
        name: name
        for name in ("None", "True", "False", "bool", "int", "float", "str", "list", "tuple",
                     "dict", "object", "bytes")
    },
    "boolean": "bool",
    "string": "str",
    "callable": "collections.abc.Callable",
    "iterable": "collections.abc.Iterable",
    "sequence": "collections.abc.Sequence",
    "mapping": "collections.abc.Mapping",
    "PathLike": "os.PathLike",
    "os.PathLike": "os.PathLike",
    "Path": "pathlib.Path",
    "logging.Logger": "logging.Logger",
    "array": "numpy.ndarray",
    "ndarray": "numpy.ndarray",
    "np.ndarray": "numpy.ndarray",
    "array_like": "numpy.typing.ArrayLike",
    "array-like": "numpy.typing.ArrayLike",
    "dtype": "numpy.dtype",
    "csr_matrix": "scipy.sparse.csr_matrix",
    "TriangleMesh": "open3d.geometry.TriangleMesh",
    "PointCloud": "open3d.geometry.PointCloud",
    "Image": "open3d.geometry.Image",
    "distributed.Client": "distributed.Client",
    "Client": "distributed.Client",
    # the package's classes (CamelCase public names; PRESETS is a constant)
    **{f"{name}": f"o3d_ofp.{name}" for name in o3d_ofp.__all__ if name[:1].isupper()
       and not name.isupper()},
}
numpydoc_validation_checks: set[str] = set()

# Keep "--flag" as typed (the CLI reference and code-like text), not typographic dashes.
smartquotes = False

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



def _reexported_data_doc(app, what, name, obj, options, lines):
    """Give a constant re-exported by ``o3d_ofp`` the ``#:`` comment of its definition.

    Autodoc reads ``#:`` comments from the module it documents (``o3d_ofp``), where these names
    are only imported, and would otherwise show the docstring of the value's type (``str``).
    """
    if what != "data" or not name.startswith("o3d_ofp."):
        return
    attr = name.rsplit(".", 1)[1]
    for info in pkgutil.walk_packages(o3d_ofp.__path__, "o3d_ofp."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        if getattr(module, attr, None) is not obj:
            continue
        comment = ModuleAnalyzer.for_module(info.name).find_attr_docs().get(("", attr))
        if comment:
            lines[:] = list(comment)
            return


def setup(app):
    """Connect the handlers above."""
    app.connect("autodoc-process-docstring", _reexported_data_doc)


html_theme = "pydata_sphinx_theme"
html_title = f"o3d_ofp {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
