#!/usr/bin/env bash
# Creates .venv and installs gns-framework with every optional part and the example plugins.
# torch is pinned first: an unpinned torch pulls several GB of CUDA packages.
# Each stage says what it does and how long it took (the whole set-up takes about 5 minutes).
set -euo pipefail
cd "$(dirname "$0")/.."
started=$SECONDS
stage() {
    local name=$1
    shift
    local begun=$SECONDS
    echo "setup: $name ..."
    "$@"
    echo "setup: $name done in $((SECONDS - begun)) s"
}
stage "virtual environment .venv" python3 -m venv .venv
stage "pip upgrade" .venv/bin/python -m pip install -q --upgrade pip
stage "torch 2.13.0 (CPU build)" .venv/bin/python -m pip install -q torch==2.13.0
stage "gns-framework with every extra (tests, evaluation, formats, MLflow, Triton)" .venv/bin/python -m pip install -q -e '.[all]'
stage "example plugin gns-clay (a material)" .venv/bin/python -m pip install -q -e plugins/examples/gns-clay
stage "example plugin gns-processor (a processor)" .venv/bin/python -m pip install -q -e plugins/examples/gns-processor
echo "setup: done in $((SECONDS - started)) s; run .venv/bin/gns demo, or .venv/bin/python -m pytest -q"
