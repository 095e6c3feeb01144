#!/usr/bin/env bash
# The documentation site: a strict Sphinx build (warnings are errors, every cross-reference
# checked) that also runs the gallery's examples. Output in docs/_build/html.
# Expects the environment made by scripts/setup.sh (the `docs` extra).
set -euo pipefail
cd "$(dirname "$0")/.."
export MPLBACKEND=Agg
rm -rf docs/_build docs/api/generated docs/auto_examples
.venv/bin/python -m sphinx -W --keep-going -n -q -b html docs docs/_build/html "$@"
echo "docs built: docs/_build/html/index.html"
