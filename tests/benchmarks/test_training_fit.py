"""benchmarks/training_fit.py: the model rolled out on its own training trajectories (first frame offsets only),
and the summary by the worse of extent and height."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from load_script import load_script

training_fit = load_script("benchmarks/training_fit.py")

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_only_the_first_frame_offset_of_each_trajectory_is_rolled_out():
    cases = [SimpleNamespace(key=k) for k in ("seed_1", "seed_1+1", "seed_1+3", "seed_2", "seed_2+2")]
    assert [c.key for c in training_fit.first_offsets(cases)] == ["seed_1", "seed_2"]


def test_the_summary_counts_the_worse_of_extent_and_height_by_obstacle():
    rows = [
        {"scene": "a", "extent": 25.0, "height": 1.0, "obstacle": True},
        {"scene": "b", "extent": 2.0, "height": 12.0, "obstacle": False},
        {"scene": "c", "extent": 1.0, "height": 0.5, "obstacle": True},
    ]
    result = training_fit.summary(rows)
    assert result["all"] == {"scenes": 3, "median_pct": 12.0, "over_10": 2, "over_15": 1}
    assert result["with_obstacle"]["over_15"] == 1 and result["without_obstacle"]["over_10"] == 1


def test_the_shipped_model_on_trajectories_of_its_envelope(tmp_path, capsys):
    from gns_framework.cli import main

    data = tmp_path / "data"
    assert main(["generate", "scenes/sand_general_2d.yaml", "--trajectories", "2", "--valid", "0", "--test", "0",
                 "--out", str(data), "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    args = ["--model", "models/sand2d_general_fast.pt", "--data", str(data), "--limit", "1", "--json"]
    assert training_fit.main(args) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (row,) = result["rows"]
    assert row["scene"].startswith("seed_") and "+" not in row["scene"]
    assert 0 <= row["extent"] < 100 and 0 <= row["height"] < 100
    assert result["all"]["scenes"] == 1
