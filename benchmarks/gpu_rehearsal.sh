#!/usr/bin/env bash
# Rehearses the device run here: a fresh virtual environment with only the packages the lent GPU
# machine's image has and the project uses (torch, numpy, pluggy, pyyaml, tqdm, scipy, h5py,
# matplotlib), a copy of what travels to the device (tracked and untracked-not-ignored files, and
# gpu_wheels/), and `gpu_check.sh --device cpu --dry-run` run in it, which installs the rest from
# gpu_wheels/ as the device run does. It passes when the check ends with no failure and the project,
# its entry points and pydantic came from the wheels. This is what says the device run gets past its
# install (tests/benchmarks/test_gpu_rehearsal.py runs it when GNS_GPU_REHEARSAL=1).
#
# Usage: benchmarks/gpu_rehearsal.sh [--keep]
# Environment:
#   GPU_REHEARSAL_PYTHON   the interpreter (default: python3.12 if a CPU build of torch installs for it
#                          here, else python3.11; pyenv's versions are looked at too)
#   GPU_REHEARSAL_TORCH    the torch requirement (default torch==2.13.0: a local CPU wheel here)
#   GPU_REHEARSAL_ANY_TORCH=1  accept a torch that is not a CPU build (several GB of CUDA packages)
#   GPU_WHEELS             the prepared folder (default gpu_wheels/; made by --prepare when it lacks
#                          the chosen Python's wheels or pyproject.toml changed since)
# Exit status: 0 pass, 1 fail, 77 cannot rehearse here (no Python 3.12/3.11 with a CPU torch).
set -u
cd "$(dirname "$0")/.."
REPO=$(pwd)
KEEP=0
[ "${1:-}" = --keep ] && KEEP=1
TORCH=${GPU_REHEARSAL_TORCH:-torch==2.13.0}
WHEELS=${GPU_WHEELS:-$REPO/gpu_wheels}
PACKAGES=(numpy pluggy pyyaml tqdm scipy h5py matplotlib)
START=$SECONDS
say() { echo "gpu_rehearsal: $*"; }

ROOT=$(mktemp -d "${TMPDIR:-/tmp}/gpu_rehearsal.XXXXXX")
cleanup() { if [ "$KEEP" = 0 ]; then rm -rf "$ROOT"; else say "kept $ROOT"; fi; }
trap cleanup EXIT

# --- the interpreter: 3.12 (the device's) when a CPU torch installs for it, else 3.11
candidates() {
  if [ -n "${GPU_REHEARSAL_PYTHON:-}" ]; then echo "$GPU_REHEARSAL_PYTHON"; return; fi
  local root=${PYENV_ROOT:-$HOME/.pyenv} v
  for v in 3.12 3.11; do
    command -v "python$v" >/dev/null 2>&1 && echo "python$v"
    ls -d "$root"/versions/"$v".*/bin/"python$v" 2>/dev/null | sort -V -r
  done
}
# torch_for PYTHON: 0 when $TORCH resolves, for PYTHON, to a CPU build or a local file (pip's report only).
torch_for() {
  local report="$ROOT/torch-report.json"
  "$1" -m pip install --dry-run --ignore-installed --no-deps -q --report "$report" "$TORCH" >/dev/null 2>&1 || return 1
  "$1" - "$report" <<'EOF'
import json, sys
found = json.load(open(sys.argv[1]))["install"][0]
url, version = found["download_info"]["url"], found["metadata"]["version"]
print(f"{version} {url}")
sys.exit(0 if "+cpu" in version or url.startswith("file:") else 3)
EOF
}
PY=""
while read -r candidate; do
  [ -n "$candidate" ] || continue
  "$candidate" -c 'import sys; assert sys.version_info >= (3, 11)' 2>/dev/null || continue
  found=$(torch_for "$candidate")
  status=$?
  if [ "$status" = 0 ] || { [ "${GPU_REHEARSAL_ANY_TORCH:-0}" = 1 ] && [ -n "$found" ]; }; then
    PY=$candidate
    say "python=$candidate torch=${found%% *}"
    break
  fi
  say "not $candidate: $TORCH there is ${found:-not installable} (not a CPU build; GPU_REHEARSAL_ANY_TORCH=1 takes it)"
done < <(candidates | awk '!seen[$0]++')
if [ -z "$PY" ]; then
  echo "skipped: no Python 3.12 or 3.11 here for which $TORCH installs as a CPU build"
  exit 77
fi
VERSION=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
TAG="cp${VERSION/./}"

# --- the prepared folder, made for this Python and the current pyproject.toml
if [ ! -d "$WHEELS/$TAG" ] || ! python3 - "$WHEELS/manifest.json" "$REPO/pyproject.toml" <<'EOF'
import hashlib, json, sys
manifest = json.load(open(sys.argv[1]))
sys.exit(0 if manifest["pyproject_sha256"] == hashlib.sha256(open(sys.argv[2], "rb").read()).hexdigest() else 1)
EOF
then
  say "preparing $WHEELS (for $VERSION and the device's 3.12)"
  GPU_WHEELS="$WHEELS" GPU_WHEELS_PYTHONS="$VERSION" bash benchmarks/gpu_check.sh --prepare || { say "fail: --prepare failed"; exit 1; }
fi

# --- a fresh venv with the device image's packages only
started=$SECONDS
"$PY" -m venv "$ROOT/venv" || { say "fail: python -m venv"; exit 1; }
VPY="$ROOT/venv/bin/python"
"$VPY" -m pip install -q --disable-pip-version-check "$TORCH" "${PACKAGES[@]}" > "$ROOT/venv.log" 2>&1 \
  || { tail -n 20 "$ROOT/venv.log"; say "fail: installing $TORCH ${PACKAGES[*]}"; exit 1; }
VENV_S=$((SECONDS - started))
for absent in pydantic gns_framework warp mlflow; do
  if "$VPY" -I -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('$absent') is None)" 2>/dev/null; then
    say "fail: the fresh venv already has $absent"; exit 1
  fi
done
say "venv=$ROOT/venv seconds=$VENV_S packages=$("$VPY" -m pip list --format=freeze 2>/dev/null | tr '\n' ' ')"

# --- what travels to the device: tracked and untracked-not-ignored files, and the prepared folder
TREE="$ROOT/tree"
mkdir -p "$TREE"
git ls-files -z --cached --others --exclude-standard | while IFS= read -r -d '' file; do
  [ -f "$file" ] && mkdir -p "$TREE/$(dirname "$file")" && cp -p "$file" "$TREE/$file"
done
cp -r "$WHEELS" "$TREE/gpu_wheels"
say "tree=$TREE mib=$(du -sm "$TREE" | cut -f1)"

# --- the device run, as on the device: plain interpreter, nothing on PYTHONPATH
started=$SECONDS
env -u PYTHONPATH PYTHON="$VPY" GPU_WHEELS="$TREE/gpu_wheels" TMPDIR="$ROOT" OMP_NUM_THREADS=1 \
  bash "$TREE/benchmarks/gpu_check.sh" --device cpu --dry-run 2>&1 | tee "$ROOT/check.log"
rc=${PIPESTATUS[0]}
CHECK_S=$((SECONDS - started))

problems=()
[ "$rc" = 0 ] || problems+=("gpu_check.sh exited $rc")
grep -q '^gpu_check: summary failures=0 ' "$ROOT/check.log" || problems+=("the summary reports failures")
grep -q '^gpu_check: part name=.* status=fail' "$ROOT/check.log" && problems+=("a part failed")
install_line=$(grep '^gpu_check: install python=' "$ROOT/check.log" | tail -n 1)
for name in gns-framework pydantic pydantic-core; do
  case "$install_line" in *"$name=="*) ;; *) problems+=("$name was not installed from the wheels") ;; esac
done
grep -q "^gpu_check: imports .*builtins=[1-9].*dist_info=$ROOT/" "$ROOT/check.log" \
  || problems+=("the registry's built-ins did not come from the installed dist-info")
grep -q '^gpu_check: part name=scale status=pass' "$ROOT/check.log" || problems+=("the scale part did not pass")
if [ ${#problems[@]} != 0 ]; then
  for p in "${problems[@]}"; do say "problem: $p"; done
  say "fail python=$VERSION venv_s=$VENV_S check_s=$CHECK_S total_s=$((SECONDS - START))"
  exit 1
fi
say "pass python=$VERSION torch=$("$VPY" -c 'import torch; print(torch.__version__)') venv_s=$VENV_S check_s=$CHECK_S total_s=$((SECONDS - START))"
