"""The Examples sections of the docstrings run, and say what they show.

Every docstring of every module of the package is collected with :mod:`doctest` and run as
its own test case; a failing example fails with the doctest report. The main public names
must keep an Examples section (the API reference shows them).
"""

from __future__ import annotations

import doctest
import importlib
import inspect
import pkgutil
import re

import pytest

import o3d_ofp

OPTIONFLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

#: Public names whose docstring must show a runnable example (name, or "Class.member").
WITH_EXAMPLES = (
    "eigenbasis",
    "ofp_basis",
    "OFPBasis",
    "OFPBasis.approximate",
    "OFPBasis.approximation_error",
    "approximation_error",
    "laplacian",
    "eigenproducts",
    "n_eigenproducts",
    "gram_schmidt",
    "match",
    "Correspondence",
    "Correspondence.from_p2p",
    "Correspondence.save",
    "Correspondence.load",
    "transfer_colors",
    "transfer_function",
    "transfer_signal",
    "transfer_matrix",
    "transfer_detail",
    "filter_geometry",
    "clean_shape",
    "hks",
    "wks",
    "fmap_from_p2p",
    "p2p_from_fmap",
    "read_geometry",
    "write_geometry",
    "cached_basis",
    "shape_digest",
    "eigenproduct_indices",
    "lift_fmap",
    "estimate_fmap",
    "zoomout_refine",
    "icp_refine",
    "nearest_neighbors",
    "p2p_from_template",
    "match_eigenbases",
    "texture_colors",
    "render_panel",
    "write_summary",
)


def _modules() -> list[str]:
    """Every module of the package but ``__main__`` (importing it runs the command line)."""
    names = [o3d_ofp.__name__]
    for info in pkgutil.walk_packages(o3d_ofp.__path__, prefix=o3d_ofp.__name__ + "."):
        if info.name.rsplit(".", 1)[-1] != "__main__":
            names.append(info.name)
    return sorted(names)


def _doctests() -> list[doctest.DocTest]:
    """Return the docstrings with examples, each once (a re-exported name is found once)."""
    finder = doctest.DocTestFinder(exclude_empty=True)
    found: dict[str, doctest.DocTest] = {}
    for name in _modules():
        module = importlib.import_module(name)
        for test in finder.find(module, name):
            if test.examples:
                found.setdefault(test.name, test)
    return [found[name] for name in sorted(found)]


DOCTESTS = _doctests()


@pytest.mark.parametrize("test", DOCTESTS, ids=[t.name for t in DOCTESTS])
def test_docstring_examples_run(test: doctest.DocTest) -> None:
    """Run one docstring's examples; on a failure, show doctest's report."""
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=OPTIONFLAGS)
    # a fresh copy of the module's globals for each run (the runner clears them afterwards)
    fresh = doctest.DocTest(
        test.examples, dict(test.globs), test.name, test.filename, test.lineno, test.docstring
    )
    result = runner.run(fresh, out=report.append)
    if result.failed:
        pytest.fail("".join(report), pytrace=False)


def _docstring(qualified: str) -> str:
    obj: object = o3d_ofp
    for part in qualified.split("."):
        obj = getattr(obj, part)
    return inspect.getdoc(obj) or ""


@pytest.mark.parametrize("name", WITH_EXAMPLES)
def test_main_names_have_examples(name: str) -> None:
    """The docstring has a numpydoc Examples section with at least one ``>>>`` line."""
    doc = _docstring(name)
    section = re.search(r"^Examples\n-{8}\n(.*?)(?=^\S[^\n]*\n-{3,}\n|\Z)", doc, flags=re.M | re.S)
    assert section is not None, f"{name}: no Examples section"
    assert re.search(r"^\s*>>> ", section.group(1), flags=re.M), f"{name}: no >>> line"


def test_examples_were_collected() -> None:
    """The collection found the examples of the main names (not an empty parametrization)."""
    collected = {t.name.rsplit(".", 1)[-1] for t in DOCTESTS}
    assert {"eigenbasis", "match", "ofp_basis"} <= collected
