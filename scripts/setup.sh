#!/usr/bin/env bash
# Creates .venv and installs gns-framework with every optional part and the example plugins.
# torch is pinned first: an unpinned torch pulls several GB of CUDA packages.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q torch==2.13.0
.venv/bin/python -m pip install -q -e '.[all]'
.venv/bin/python -m pip install -q -e plugins/examples/gns-clay
.venv/bin/python -m pip install -q -e plugins/examples/gns-processor
