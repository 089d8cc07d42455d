#!/usr/bin/env bash
# The GPU check: install what the machine lacks, imports, CUDA tests, training + resume, rollout,
# DDP, node sums, a chunked step against the CPU, the Triton edge block against the chunked one, captured
# rollout and training steps against eager ones, step
# time and peak memory by scene size and precision, many small scenes batched in capacity classes against one at a
# time, and the MPM on CUDA. Every part has its own time limit and the whole run a budget
# (450 s, install included), so it ends within 8 minutes on one GPU; exits non-zero when any part fails.
#
# Usage: benchmarks/gpu_check.sh --prepare                 # here, with network: fill gpu_wheels/
#        benchmarks/gpu_check.sh [--device cuda|cpu] [--dry-run] [--budget-s S]
#   --prepare   build the project's wheel and download every wheel the GPU machine lacks
#               (benchmarks/gpu_wheels.py) for CPython 3.12 (the device) and this Python, under 64 MiB.
#   --dry-run   small sizes and few steps: checks that every part runs (the test suite runs
#               `--device cpu --dry-run`; benchmarks/gpu_rehearsal.sh in a bare venv); the figures mean nothing.
# Environment: PYTHON (default: the repository's .venv when present, else python3), GPU_WHEELS
# (default gpu_wheels/), GPU_CHECK_LOGS (part logs; default a temporary folder), GPU_CHECK_BUDGET_S.
#
# Output (docs/performance.md): one line per result, `gpu_check: <part> key=value ...`, printed as
# soon as it is measured; each part ends with `gpu_check: part name=<part> status=pass|fail|skip
# seconds=<s> limit=<s>` (a skip adds ` skipped: <why>`), the run with `gpu_check: summary ...`.
set -u
cd "$(dirname "$0")/.."
REPO=$(pwd)

DEVICE=cuda
DRY=0
PREPARE=0
BUDGET=${GPU_CHECK_BUDGET_S:-}
while [ $# -gt 0 ]; do
  case "$1" in
    --device) DEVICE="$2"; shift 2 ;;
    --dry-run) DRY=1; shift ;;
    --prepare) PREPARE=1; shift ;;
    --budget-s) BUDGET="$2"; shift 2 ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) echo "gpu_check.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$DEVICE" in cuda|cpu) ;; *) echo "gpu_check.sh: --device must be cuda or cpu, got $DEVICE" >&2; exit 2 ;; esac

if [ -z "${PYTHON:-}" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PYTHON="$REPO/.venv/bin/python"; else PYTHON=python3; fi
fi
WHEELS=${GPU_WHEELS:-$REPO/gpu_wheels}
export PYTHONUNBUFFERED=1

if [ "$PREPARE" = 1 ]; then
  # The device's Python (3.12) always; also the rehearsal's (GPU_WHEELS_PYTHONS, default: python3's here).
  PYTHONS=${GPU_WHEELS_PYTHONS:-$(python3 -c 'import sys; print("%d.%d" % sys.version_info[:2])')}
  FLAGS=()
  for v in $PYTHONS; do FLAGS+=(--python "$v"); done
  exec "$PYTHON" benchmarks/gpu_wheels.py prepare --out "$WHEELS" "${FLAGS[@]}"
fi

if [ -z "$BUDGET" ]; then
  if [ "$DRY" = 1 ]; then BUDGET=900; else BUDGET=450; fi  # a dry run on a loaded CPU is slow; its limits still hold
fi
WORK=$(mktemp -d "${TMPDIR:-/tmp}/gpu_check.XXXXXX")
LOGS=${GPU_CHECK_LOGS:-$WORK/logs}
mkdir -p "$LOGS"
echo "gpu_check: start device=$DEVICE dry_run=$DRY budget_s=$BUDGET python=$PYTHON work=$WORK logs=$LOGS"
export MLFLOW_TRACKING_URI="sqlite:///$WORK/mlflow.db"

FAILURES=0
SKIPS=0
PARTS=0
START=$SECONDS
# part NAME LIMIT_S COMMAND...: run it within its limit and what is left of the budget. Its
# `gpu_check:` lines stream to stdout as they come; the whole output goes to $LOGS/NAME.log.
# Exit status 77 (a line `skipped: <why>` before it) is a skip, anything else non-zero a failure.
part() {
  local name=$1 limit=$2
  shift 2
  PARTS=$((PARTS + 1))
  local left=$((BUDGET - (SECONDS - START) - 5))
  if [ "$left" -lt 10 ]; then
    SKIPS=$((SKIPS + 1))
    echo "gpu_check: part name=$name status=skip seconds=0 limit=0 skipped: over_budget (${left}s of the run's ${BUDGET}s left)"
    return
  fi
  [ "$left" -lt "$limit" ] && limit=$left
  local started=$SECONDS status rc
  rm -f "$LOGS/$name.rc"
  { GPU_CHECK_PART_LIMIT_S=$limit timeout --kill-after=5 "$limit" "$@" 2>&1; echo $? > "$LOGS/$name.rc"; } \
    | tee "$LOGS/$name.log" | grep --line-buffered '^gpu_check: '
  rc=$(cat "$LOGS/$name.rc" 2>/dev/null || echo 1)
  local why=""
  case "$rc" in
    0) status=pass ;;
    77) status=skip; SKIPS=$((SKIPS + 1)); why=$(grep '^skipped: ' "$LOGS/$name.log" | tail -n 1) ;;
    *) status=fail; FAILURES=$((FAILURES + 1))
       [ "$rc" = 124 ] || [ "$rc" = 137 ] && why="timed_out=${limit}s"
       echo "--- $name failed (exit $rc, limit ${limit}s); last lines of $LOGS/$name.log:" >&2
       tail -n 25 "$LOGS/$name.log" >&2 ;;
  esac
  echo "gpu_check: part name=$name status=$status seconds=$((SECONDS - started)) limit=$limit${why:+ $why}"
}
# skip NAME WHY: a part not run here.
skip() {
  PARTS=$((PARTS + 1))
  SKIPS=$((SKIPS + 1))
  echo "gpu_check: part name=$1 status=skip seconds=0 limit=0 skipped: $2"
}
summary() {
  echo "gpu_check: summary failures=$FAILURES skips=$SKIPS parts=$PARTS seconds=$((SECONDS - START)) budget_s=$BUDGET"
}

# What the interpreter lacks (pydantic, gns-framework and its entry points, ...) from gpu_wheels/
# into a fresh folder on PYTHONPATH; nothing when it has everything (the repository's .venv).
SITE="$WORK/site"
part install 60 "$PYTHON" benchmarks/gpu_wheels.py install --wheels "$WHEELS" --target "$SITE"
if [ "$FAILURES" != 0 ]; then
  echo "gpu_check: the install failed: no other part can run (run benchmarks/gpu_check.sh --prepare here and carry gpu_wheels)" >&2
  summary
  exit 1
fi
if [ -d "$SITE" ]; then
  # The working tree's code first, then the installed wheels (the project's dist-info: its entry points).
  export PYTHONPATH="$REPO:$REPO/plugins:$SITE${PYTHONPATH:+:$PYTHONPATH}"
fi

if [ "$DRY" = 1 ]; then
  STEPS=4; MORE=6; ROLLOUT_STEPS=3
  SCALE=(--sizes 500 --precisions float32 bfloat16 --repeat 1)
  SUMS=(--rows 20000 --chunk-rows 2000 --repeat 3)
  CHUNKS=(--particles 500)
  CAPTURE=(--sizes 300 --steps 3 --compile-backend eager)
  TRAIN_CAPTURE=(--particles 200 --warmup 4 --steps 2)
  BATCHED=(--scenes 6 --particles 40 80 --steps 3 --batch 3)
  KERNELS=(--small --sizes 64 --precisions float32 --repeat 1 --profile-rows 3)
  MPM=(--grid 24 --frames 3)
else
  STEPS=30; MORE=40; ROLLOUT_STEPS=15
  SCALE=(--sizes 10000 100000 1000000 --repeat 5)
  SUMS=(--rows 4194304 --chunk-rows 262144 --repeat 10)
  CHUNKS=(--particles 10000)
  CAPTURE=(--sizes 300 10000 100000 --steps 20)
  TRAIN_CAPTURE=(--particles 10000 --warmup 12 --steps 20)
  BATCHED=(--scenes 32 --particles 250 350 --steps 57 --batch 16)
  KERNELS=(--sizes 10000 100000 --precisions float32 bfloat16 --repeat 5 --profile-rows 15)
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

part imports 40 "$PYTHON" benchmarks/gpu_check.py imports
part info 30 "$PYTHON" benchmarks/gpu_check.py info --device "$DEVICE"
if [ "$DEVICE" = cuda ]; then
  # The CUDA tests, and the precision getters under this machine's torch.
  part cuda_tests 90 "$PYTHON" benchmarks/gpu_check.py tests tests/test_cuda.py tests/runtime/test_precision.py tests/runtime/test_tf32.py \
    tests/builtins/_kernels/test_triton_edge_block.py tests/builtins/_kernels/test_triton_kernels.py \
    tests/model/test_captured_steps.py tests/runtime/test_capture.py
else
  skip cuda_tests "--device cpu (the cuda-marked tests need a GPU; the test suite runs the rest)"
fi
part data 30 "$PYTHON" benchmarks/gpu_check.py data "$WORK/data"
part train 50 "$PYTHON" -m gns_framework.cli train "$RECIPE" --out "$WORK/run" --no-progress --no-tracking
part resume 35 "$PYTHON" -m gns_framework.cli train "$RECIPE" --out "$WORK/run" --steps "$MORE" --resume --no-progress --no-tracking
part rollout 35 "$PYTHON" -m gns_framework.cli rollout "$WORK/run/checkpoints/checkpoint-$(printf '%09d' "$MORE").pt" \
  --device "$DEVICE" --steps "$ROLLOUT_STEPS" --out "$WORK/rollouts" --no-progress
GPUS=0
[ "$DEVICE" = cuda ] && GPUS=$("$PYTHON" -c 'import torch; print(torch.cuda.device_count())' 2>/dev/null || echo 0)
if [ "$GPUS" -ge 2 ] && [ "$DRY" = 0 ]; then
  echo "gpu_check: ddp ranks=$GPUS backend=nccl launcher=torchrun"
  part ddp 60 "$PYTHON" -m torch.distributed.run --nnodes 1 --nproc-per-node "$GPUS" --master-addr 127.0.0.1 \
    --master-port 29533 -m gns_framework.cli train "$RECIPE" --out "$WORK/ddp" --steps 20 --no-progress --no-tracking
else
  # One GPU (or the CPU): a real process group of one rank (NCCL; gloo on the CPU) and DDP steps through it.
  part ddp 45 "$PYTHON" benchmarks/gpu_check.py ddp --device "$DEVICE"
fi
part sums 30 "$PYTHON" benchmarks/gpu_check.py sums --device "$DEVICE" "${SUMS[@]}"
part chunks 40 "$PYTHON" benchmarks/gpu_check.py chunks --device "$DEVICE" "${CHUNKS[@]}"
# The Triton edge block against the chunked path, bitwise repeatability, a kernel table per path. On the
# CPU (the dry run) the kernels run in Triton's interpreter, which must be on before triton is imported.
if [ "$DEVICE" = cpu ]; then
  part kernels 120 env TRITON_INTERPRET=1 "$PYTHON" benchmarks/edge_kernels.py --device cpu "${KERNELS[@]}"
else
  part kernels 100 "$PYTHON" benchmarks/edge_kernels.py --device cuda "${KERNELS[@]}"
fi
# Rollout steps on the fixed-capacity graph, eager against one captured CUDA graph (issue 45, item 4).
part capture 45 "$PYTHON" benchmarks/gpu_check.py capture --device "$DEVICE" "${CAPTURE[@]}"
part scale 130 "$PYTHON" benchmarks/gpu_check.py scale --device "$DEVICE" "${SCALE[@]}"
# Many small scenes, one at a time against batches replaying their capacity classes' captures (item 5).
part batched 50 "$PYTHON" benchmarks/gpu_check.py batched --device "$DEVICE" "${BATCHED[@]}"
# Training steps eager against replayed from captures, batches padded to capacity classes (item 4).
part train_capture 40 "$PYTHON" benchmarks/gpu_check.py train_capture --device "$DEVICE" "${TRAIN_CAPTURE[@]}"
part mpm 40 "$PYTHON" benchmarks/gpu_check.py mpm --device "$DEVICE" "${MPM[@]}"

summary
[ "$FAILURES" = 0 ]
