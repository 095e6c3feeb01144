#!/usr/bin/env bash
# The test suite: lint, the documentation site (strict build, runs the gallery), the fast
# tests, then the slow (@pytest.mark.slow) ones.
# Expects the environment made by scripts/setup.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/python -m ruff check .
bash scripts/docs.sh
# Two worker processes (pytest-xdist), one a core of the 2-core CI machine: the fast tests take
# 7.8 minutes instead of 9.8 (measured on this machine, one run each).
.venv/bin/python -m pytest -n 2 "$@"
# Exit code 5 means "no slow tests collected" (e.g. when -k filters them all out): not a failure.
.venv/bin/python -m pytest -m slow -n 2 "$@" || [ $? -eq 5 ]
