#!/usr/bin/env bash
# Set up o3d_ofp on Debian 12 / Ubuntu: the system libraries Open3D loads, a virtual
# environment in .venv, and the package (editable) with CPU-only Open3D and the test tools.
# Run from anywhere; needs root or sudo for apt-get.
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
PYTHON="${PYTHON:-python3}"
APT_PACKAGES="libgl1 libegl1 libusb-1.0-0"
# Debian's own python3 ships venv/ensurepip separately.
if ! "$PYTHON" -c "import ensurepip, venv" 2>/dev/null; then APT_PACKAGES="$APT_PACKAGES python3-venv"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
# shellcheck disable=SC2086
$SUDO apt-get install -y -qq --no-install-recommends $APT_PACKAGES >/dev/null
"$PYTHON" -c 'import sys; assert sys.version_info >= (3, 10), "o3d_ofp needs Python >= 3.10, found " + sys.version'
"$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# within the NumPy / SciPy releases the suite was last run green with (see the file)
.venv/bin/python -m pip install -q -e ".[cpu,dask,test,docs]" -c scripts/constraints.txt
.venv/bin/python -c "import open3d, o3d_ofp; print('o3d_ofp', o3d_ofp.__version__, 'with Open3D', open3d.__version__, 'ready in .venv')"
