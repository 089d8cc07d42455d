#!/usr/bin/env bash
# The GPU check: CUDA tests, training + resume, rollout, DDP over NCCL, step time and peak memory
# by scene size and precision, and the MPM on CUDA. Installs nothing; runs in at most ~8 minutes
# on one GPU (every part has its own time limit, 480 s in all); exits non-zero when any part fails.
#
# Usage: benchmarks/gpu_check.sh [--device cuda|cpu] [--dry-run]
#   --dry-run   small sizes and few steps: checks that every part runs (the test suite runs
#               `--device cpu --dry-run`); the figures mean nothing.
# Environment: PYTHON (default: python3 on PATH; the repository's .venv when present).
#
# Output (docs/performance.md): one line per result, `gpu_check: <part> key=value ...`;
# each part ends with `gpu_check: part name=<part> status=pass|fail|skip seconds=<s>`, the
# run with `gpu_check: summary failures=<n> parts=<n>`. Part logs go to $GPU_CHECK_LOGS
# (default: a temporary folder, printed), a failed part's tail also to stderr.
set -u
cd "$(dirname "$0")/.."
REPO=$(pwd)

DEVICE=cuda
DRY=0
while [ $# -gt 0 ]; do
  case "$1" in
    --device) DEVICE="$2"; shift 2 ;;
    --dry-run) DRY=1; shift ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) echo "gpu_check.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$DEVICE" in cuda|cpu) ;; *) echo "gpu_check.sh: --device must be cuda or cpu, got $DEVICE" >&2; exit 2 ;; esac

if [ -z "${PYTHON:-}" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PYTHON="$REPO/.venv/bin/python"; else PYTHON=python3; fi
fi
WORK=$(mktemp -d "${TMPDIR:-/tmp}/gpu_check.XXXXXX")
LOGS=${GPU_CHECK_LOGS:-$WORK/logs}
mkdir -p "$LOGS"
echo "gpu_check: start device=$DEVICE dry_run=$DRY work=$WORK logs=$LOGS"
export MLFLOW_TRACKING_URI="sqlite:///$WORK/mlflow.db"

FAILURES=0
PARTS=0
# part NAME LIMIT_S COMMAND...: run it with a time limit; its `gpu_check:` lines go to stdout.
part() {
  local name=$1 limit=$2
  shift 2
  PARTS=$((PARTS + 1))
  local started=$SECONDS status
  if timeout --kill-after=10 "$limit" "$@" > "$LOGS/$name.log" 2>&1; then status=pass; else status=fail; fi
  grep '^gpu_check: ' "$LOGS/$name.log"
  if [ "$status" = fail ]; then
    FAILURES=$((FAILURES + 1))
    echo "--- $name failed (limit ${limit}s); last lines of $LOGS/$name.log:" >&2
    tail -n 25 "$LOGS/$name.log" >&2
  fi
  echo "gpu_check: part name=$name status=$status seconds=$((SECONDS - started))"
}
# skip NAME REASON: a part not run here; REASON is one word.
skip() {
  PARTS=$((PARTS + 1))
  echo "gpu_check: part name=$1 status=skip reason=$2"
}

if [ "$DRY" = 1 ]; then
  STEPS=4; MORE=6; ROLLOUT_STEPS=3
  SCALE=(--sizes 500 --precisions float32 bfloat16 --repeat 1)
  MPM=(--grid 24 --frames 3)
else
  STEPS=30; MORE=40; ROLLOUT_STEPS=15
  SCALE=(--sizes 10000 100000 1000000 --repeat 5)
  MPM=(--grid 96 --frames 10)
fi

RECIPE="$WORK/recipe.yaml"
cat > "$RECIPE" <<EOF
name: gpu-check
dataset: {name: safe, path: $WORK/data}
model:
  latent_size: 64
  mlp_hidden_size: 64
  processor: {name: interaction_network, message_passing_steps: 5}
training:
  steps: $STEPS
  batch_size: 2
  log_every: 10
  validate_every: 1000
  checkpoint_every: 10
  device: $DEVICE
EOF

part info 30 "$PYTHON" benchmarks/gpu_check.py info --device "$DEVICE"
if [ "$DEVICE" = cuda ]; then
  part cuda_tests 90 "$PYTHON" -m pytest -q -p no:cacheprovider -m cuda tests/test_cuda.py
else
  skip cuda_tests cpu_run  # the cuda-marked tests skip themselves on the CPU
fi
part data 30 "$PYTHON" benchmarks/gpu_check.py data "$WORK/data"
part train 50 "$PYTHON" -m gns_framework.cli train "$RECIPE" --out "$WORK/run" --no-progress --no-tracking
part resume 35 "$PYTHON" -m gns_framework.cli train "$RECIPE" --out "$WORK/run" --steps "$MORE" --resume --no-progress --no-tracking
part rollout 35 "$PYTHON" -m gns_framework.cli rollout "$WORK/run/checkpoints/checkpoint-$(printf '%09d' "$MORE").pt" \
  --device "$DEVICE" --steps "$ROLLOUT_STEPS" --out "$WORK/rollouts" --no-progress
if [ "$DEVICE" = cuda ] && [ "$DRY" = 0 ]; then
  GPUS=$("$PYTHON" -c 'import torch; print(torch.cuda.device_count())')
  echo "gpu_check: ddp ranks=$GPUS backend=nccl"
  part ddp 60 "$PYTHON" -m torch.distributed.run --nnodes 1 --nproc-per-node "$GPUS" --master-addr 127.0.0.1 \
    --master-port 29533 -m gns_framework.cli train "$RECIPE" --out "$WORK/ddp" --steps 20 --no-progress --no-tracking
else
  skip ddp "$([ "$DEVICE" = cpu ] && echo cpu_run || echo dry_run)"  # NCCL needs GPUs; the gloo DDP tests cover the CPU
fi
part scale 110 "$PYTHON" benchmarks/gpu_check.py scale --device "$DEVICE" --budget-s 95 "${SCALE[@]}"
part mpm 40 "$PYTHON" benchmarks/gpu_check.py mpm --device "$DEVICE" "${MPM[@]}"

echo "gpu_check: summary failures=$FAILURES parts=$PARTS"
[ "$FAILURES" = 0 ]
