"""benchmarks/gpu_check.sh runs every part it can on the CPU (--device cpu --dry-run) and prints its documented lines."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _lines(output: str) -> list[dict[str, str]]:
    """``gpu_check: <part> key=value ...`` lines as dicts with the part under ``part``."""
    parsed = []
    for line in output.splitlines():
        if line.startswith("gpu_check: "):
            part, *pairs = line[len("gpu_check: "):].split()
            parsed.append({"part": part, **dict(pair.split("=", 1) for pair in pairs)})
    return parsed


def test_the_dry_run_passes_every_cpu_part_and_reports_in_the_documented_format(tmp_path):
    environment = dict(os.environ, PYTHON=sys.executable, TMPDIR=str(tmp_path), OMP_NUM_THREADS="1")
    result = subprocess.run(
        ["bash", str(REPO / "benchmarks" / "gpu_check.sh"), "--device", "cpu", "--dry-run"],
        capture_output=True, text=True, env=environment, timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    lines = _lines(result.stdout)
    parts = {line["name"]: line["status"] for line in lines if line["part"] == "part"}
    assert parts == {
        "info": "pass", "cuda_tests": "skip", "data": "pass", "train": "pass", "resume": "pass",
        "rollout": "pass", "ddp": "skip", "scale": "pass", "mpm": "pass",
    }
    steps = [line for line in lines if line["part"] == "step"]
    assert {(s["precision"], s["phase"]) for s in steps} == {
        (p, phase) for p in ("float32", "bfloat16") for phase in ("rollout", "train")
    }
    assert all(s["status"] == "ok" and float(s["step_s"]) > 0 and int(s["edges"]) > 0 for s in steps)
    assert [line["finite"] for line in lines if line["part"] == "mpm"] == ["True"]
    assert lines[-1] == {"part": "summary", "failures": "0", "parts": str(len(parts))}


def test_a_failing_part_fails_the_check(tmp_path):
    """A rollout of a checkpoint that is not there: the part fails, and so does the script."""
    environment = dict(os.environ, PYTHON=sys.executable, TMPDIR=str(tmp_path), OMP_NUM_THREADS="1")
    script = (REPO / "benchmarks" / "gpu_check.sh").read_text().replace("--steps \"$MORE\" --resume", "--steps 5 --resume")
    broken = tmp_path / "gpu_check.sh"
    script = script.replace('cd "$(dirname "$0")/.."', f'cd "{REPO}"')
    # Only the parts up to the rollout: the failure is the point, not the figures.
    script = "\n".join(line for line in script.splitlines() if not line.startswith(("part scale", "part mpm")))
    broken.write_text(script)
    result = subprocess.run(["bash", str(broken), "--device", "cpu", "--dry-run"], capture_output=True, text=True,
                            env=environment, timeout=300)
    assert result.returncode != 0
    parts = {line["name"]: line["status"] for line in _lines(result.stdout) if line["part"] == "part"}
    assert parts["rollout"] == "fail" and parts["train"] == "pass"
