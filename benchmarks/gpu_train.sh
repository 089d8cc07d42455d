#!/usr/bin/env bash
# Train a recipe on one GPU for a fixed time and leave its run folder where the caller says, to go on anywhere
# (issue 46, item 4). The recipe's data is generated there first when its folder is absent (the MPM on the same
# device), then `gns train --time-limit` stops after MINUTES of training with a checkpoint of the last step;
# `gns train RECIPE --out OUT --resume` goes on from it, on the CPU too.
#
# Usage: benchmarks/gpu_train.sh RECIPE OUT [MINUTES] [--device cuda|cpu] [--resume]
#   RECIPE   a recipe whose comment holds its data command (`# Data: gns generate ...`), as the shipped ones do,
#            or GENERATE set to the arguments of `gns generate` that make its data
#   OUT      the run folder: checkpoints, metrics.jsonl (on the device machine, put it under $OUT to bring it back)
#   MINUTES  training time (default 10); data generation and installation come before it
#   --resume go on from OUT's newest checkpoint (a run brought back and carried again)
# Environment: PYTHON (default: the repository's .venv when present, else python3), GPU_WHEELS (default
# gpu_wheels/, filled here by `benchmarks/gpu_check.sh --prepare`), GENERATE.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$(pwd)

DEVICE=cuda
RESUME=()
POSITIONAL=()
while [ $# -gt 0 ]; do
  case "$1" in
    --device) DEVICE="$2"; shift 2 ;;
    --resume) RESUME=(--resume); shift ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    -*) echo "gpu_train.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) POSITIONAL+=("$1"); shift ;;
  esac
done
if [ "${#POSITIONAL[@]}" -lt 2 ] || [ "${#POSITIONAL[@]}" -gt 3 ]; then
  echo "gpu_train.sh: expected RECIPE OUT [MINUTES] (see --help)" >&2
  exit 2
fi
RECIPE=${POSITIONAL[0]}
OUT=${POSITIONAL[1]}
MINUTES=${POSITIONAL[2]:-10}
[ -f "$RECIPE" ] || { echo "gpu_train.sh: $RECIPE: recipe not found" >&2; exit 2; }

if [ -z "${PYTHON:-}" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PYTHON="$REPO/.venv/bin/python"; else PYTHON=python3; fi
fi
WHEELS=${GPU_WHEELS:-$REPO/gpu_wheels}
export PYTHONUNBUFFERED=1
# What the interpreter lacks, from the carried wheels; nothing when it has everything (the repository's .venv).
SITE=$(mktemp -d "${TMPDIR:-/tmp}/gpu_train.XXXXXX")/site
if [ -d "$WHEELS" ]; then
  "$PYTHON" benchmarks/gpu_wheels.py install --wheels "$WHEELS" --target "$SITE"
fi
if [ -d "$SITE" ]; then
  export PYTHONPATH="$REPO:$REPO/plugins:$SITE${PYTHONPATH:+:$PYTHONPATH}"
fi
gns() { "$PYTHON" -m gns_framework.cli "$@"; }

DATA=$("$PYTHON" -c 'import sys, yaml; print(yaml.safe_load(open(sys.argv[1]))["dataset"]["path"])' "$RECIPE")
if [ ! -d "$DATA" ]; then
  if [ -z "${GENERATE:-}" ]; then
    GENERATE=$(sed -n 's/^# Data: gns generate //p' "$RECIPE" | head -n 1)
  fi
  [ -n "$GENERATE" ] || { echo "gpu_train.sh: $DATA is absent and $RECIPE names no data command: set GENERATE" >&2; exit 2; }
  echo "gpu_train: generating $DATA: gns generate $GENERATE --device $DEVICE"
  # shellcheck disable=SC2086  # GENERATE is a list of arguments
  gns generate $GENERATE --device "$DEVICE" --no-progress
fi

echo "gpu_train: training $RECIPE on $DEVICE for $MINUTES min into $OUT"
gns train "$RECIPE" --out "$OUT" --device "$DEVICE" --time-limit "$MINUTES" --no-tracking --no-progress "${RESUME[@]}"
echo "gpu_train: done; go on anywhere with: gns train $RECIPE --out $OUT --resume"
