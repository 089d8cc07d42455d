"""benchmarks/gpu_train.sh, run on the CPU: the data its recipe's comment names is made when absent, training stops
at the time limit with a checkpoint, and the run goes on from it with --resume."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml
from scene_builders import column_collapse
from tiny import tiny_recipe_mapping

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "gpu_train.sh"


def _run(*args: str, **env: str) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHON": sys.executable, "GPU_WHEELS": "/nonexistent", "OMP_NUM_THREADS": "1", **env}
    return subprocess.run(
        ["bash", str(SCRIPT), *args, "--device", "cpu"], capture_output=True, text=True, env=environment, timeout=600
    )


def test_data_made_from_the_recipes_comment_then_a_time_limited_run_that_resumes(tmp_path):
    scene = tmp_path / "column.yaml"
    scene.write_text(yaml.safe_dump(column_collapse(0.1, 0.1, 0.7, frames=12)))
    data, run = tmp_path / "data", tmp_path / "run"
    raw = tiny_recipe_mapping(data)
    raw["training"].update(steps=4, log_every=1, validate_every=2)
    recipe = tmp_path / "recipe.yaml"
    comment = f"# Data: gns generate {scene} --trajectories 4 --valid 1 --test 1 --out {data}\n"
    recipe.write_text(comment + yaml.safe_dump(raw))

    stopped = _run(str(recipe), str(run), "0.0001")  # 6 ms: the first step is past it
    assert stopped.returncode == 0, stopped.stderr[-3000:]
    assert f"gpu_train: generating {data}" in stopped.stdout and (data / "metadata.json").is_file()
    assert "stopped at the time limit (0.0001 min) at step 1 of 4" in stopped.stdout
    assert sorted(p.name for p in (run / "checkpoints").glob("checkpoint-*.pt")) == ["checkpoint-000000001.pt"]

    resumed = _run(str(recipe), str(run), "5", "--resume")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "generating" not in resumed.stdout and "resumed from" in resumed.stdout
    assert "trained tiny to step 4" in resumed.stdout


def test_a_recipe_without_data_or_data_command_is_refused(tmp_path):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(tmp_path / "absent")))
    refused = _run(str(recipe), str(tmp_path / "run"))
    assert refused.returncode == 2 and "names no data command: set GENERATE" in refused.stderr
    assert _run(str(recipe)).returncode == 2  # OUT missing
