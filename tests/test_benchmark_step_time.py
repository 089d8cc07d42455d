"""benchmarks/step_time.py keeps its documented JSON interface (issue 8), so results stay comparable."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "step_time.py"
REQUIRED = (
    "particles", "edges", "mean_neighbours", "train_step_s", "rollout_step_s",
    "neighbour_search_s", "peak_rss_mb", "efficiency",
)


@pytest.mark.parametrize(("dim", "precision"), [(2, "float32"), (3, "bfloat16")])
def test_one_scene_prints_one_json_object_with_every_figure(dim, precision):
    command = [sys.executable, str(SCRIPT), "--particles", "300", "--dim", str(dim), "--repeat", "1", "--warmup", "0",
               "--threads", "1", "--precision", precision, "--json"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    for key in REQUIRED:
        assert figures[key] > 0, key
    assert figures["dim"] == dim and figures["precision"] == precision
    assert abs(figures["particles"] - 300) < 0.2 * 300
    assert figures["edges"] == pytest.approx(figures["particles"] * (figures["mean_neighbours"] + 1))
    assert 5 < figures["mean_neighbours"] < 30
