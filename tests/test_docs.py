"""The documentation site covers the public API (scripts/docs.sh runs the strict build)."""

import re
import shlex
import sys
from pathlib import Path

import pytest

import o3d_ofp
from o3d_ofp.cli.main import build_parser

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_every_public_name_has_an_api_page():
    """Each name of ``o3d_ofp.__all__`` is listed in an autosummary table (one page each)."""
    listed = re.findall(r"^   (\w+)$", (DOCS / "api" / "index.rst").read_text(), flags=re.M)
    assert len(listed) == len(set(listed)), "a name is listed twice"
    assert sorted(set(o3d_ofp.__all__) - set(listed)) == []
    assert sorted(set(listed) - set(o3d_ofp.__all__)) == []


def test_the_cli_reference_is_generated_from_the_parser():
    """No flag text is written twice: the CLI page renders the parser itself."""
    page = (DOCS / "cli.md").read_text()
    assert ":module: o3d_ofp.cli.main" in page and ":func: build_parser" in page
    assert "--map" not in page


def _commands() -> list[tuple[str, str]]:
    """Every ``o3d-ofp ...`` line of a bash block in the README and the documentation pages."""
    pages = [DOCS.parent / "README.md", *sorted(DOCS.rglob("*.md"))]
    found = []
    for page in pages:
        if "_build" in page.parts:
            continue
        for block in re.findall(r"```(?:bash|sh|console)\n(.*?)```", page.read_text(), flags=re.S):
            for line in block.splitlines():
                line = line.strip().removeprefix("$ ").removeprefix(".venv/bin/")
                if line.startswith("o3d-ofp "):
                    found.append((page.relative_to(DOCS.parent).as_posix(), line))
    return found


COMMANDS = _commands()


def test_the_pages_show_commands():
    assert len(COMMANDS) > 20


@pytest.mark.parametrize(("page", "line"), COMMANDS, ids=[f"{p}:{c[:40]}" for p, c in COMMANDS])
def test_every_command_shown_parses(page, line):
    """The commands the pages show are accepted by the parser (flags renamed or gone fail)."""
    words = shlex.split(line.split("  #")[0].split(" # ")[0])
    if "&&" in words:
        words = words[: words.index("&&")]
    try:
        build_parser().parse_args(words[1:])
    except SystemExit as exit_:
        pytest.fail(f"{page}: {line!r} is refused by the parser (exit {exit_.code})")


@pytest.fixture(scope="module")
def url_for():
    """Return the offline resolver of docs/_ext (an extension module, not in the package)."""
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        from offline_xref import url_for
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    return url_for


def test_references_to_other_projects_resolve_only_when_the_name_exists(url_for):
    """The offline stand-in for intersphinx links real names and leaves misspelt ones broken."""
    numpy_page = "https://numpy.org/doc/stable/reference/generated/numpy.ndarray.html"
    assert url_for("numpy.ndarray") == url_for("np.ndarray") == numpy_page
    assert url_for("scipy.sparse.csr_matrix").endswith("generated/scipy.sparse.csr_matrix.html")
    stdlib = url_for("collections.abc.Mapping")
    assert stdlib.endswith("/collections.abc.html#collections.abc.Mapping")
    assert url_for("print").endswith("functions.html#print")
    # broken names stay broken, so that the strict build fails on them
    for name in ("numpy.nadarray", "scipy.sparse.csr_martix", "pathlib.Paht", "foo.bar"):
        assert url_for(name) is None, name
    # ours are never sent elsewhere: they must resolve in the build itself
    assert url_for("o3d_ofp.match") is None


def test_open3d_references_link_the_class_page(url_for):
    pytest.importorskip("open3d", reason="Open3D's names are looked up in the installed package")
    page = "https://www.open3d.org/docs/release/python_api/open3d.geometry.TriangleMesh.html"
    assert url_for("open3d.geometry.TriangleMesh") == url_for("o3d.geometry.TriangleMesh") == page
    assert url_for("open3d.geometry.TriangleMesh.vertices") == (
        page + "#open3d.geometry.TriangleMesh.vertices"
    )
    assert url_for("open3d.geometry.TriangleMes") is None
