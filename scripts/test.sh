#!/usr/bin/env bash
# The test suite: lint, the documentation site (strict build, runs the gallery), the fast
# tests, then the slow (@pytest.mark.slow) ones.
# Expects the environment made by scripts/setup.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/python -m ruff check .
bash scripts/docs.sh
.venv/bin/python -m pytest "$@"
# Exit code 5 means "no slow tests collected" (e.g. when -k filters them all out): not a failure.
.venv/bin/python -m pytest -m slow "$@" || [ $? -eq 5 ]
