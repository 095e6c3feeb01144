"""The documentation site covers the public API (scripts/docs.sh runs the strict build)."""

import re
from pathlib import Path

import o3d_ofp

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
