"""benchmarks/obstacle_friction.py: the same drawn scenes rerun with each obstacle's friction pinned, compared with the
data's deposits."""

from __future__ import annotations

import json

import pytest
import yaml
from load_script import load_script

obstacle_friction = load_script("benchmarks/obstacle_friction.py")

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SCENE = {
    "name": "sliding_onto_a_slab",
    "dim": 2,
    "domain": {"bounds": [[0.0, 1.0], [0.0, 0.5]], "grid": 16},
    "time": {"frame_dt": 0.01, "substeps": 10, "frames": 12},
    "blocks": [
        {
            "material": "sand",
            "position": [{"range": [0.1, 0.15]}, 0.13],
            "size": [0.15, 0.1],
            "velocity": [1.5, 0.0],
            "properties": {"friction": {"range": [0.6, 0.8]}},
        }
    ],
    "obstacles": [
        {"material": "rigid", "position": [0.0, 0.0], "size": [1.0, 0.125], "friction": {"range": [0.2, 0.8]}}
    ],
}


def test_pinned_frictions_rerun_the_data_s_scenes_and_move_the_sliding_deposit(tmp_path, capsys):
    scene = tmp_path / "slab.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    args = ["--scene", str(scene), "--seed", "5", "--held-out", "2", "--frictions", "0.0", "1.0", "--out"]
    assert obstacle_friction.main([*args, str(tmp_path / "out"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rows = result["rows"]
    assert [row["seed"] for row in rows] == [5, 5] and all(0.2 <= row["drawn"][0] <= 0.8 for row in rows)
    for row in rows:
        # Sand launched along a slab: held at its base by a rough one it shears out, on a frictionless one it slides
        # as a block; the two deposits differ by far more than the lattice's few per cent.
        assert abs(row["runs"]["0"]["extent"] - row["runs"]["1"]["extent"]) > 10, row
    assert result["scenes_with_obstacles"] == 2
    assert result["largest_span_pct"] == max(obstacle_friction.span(row) for row in rows) > 0


def test_the_span_is_the_largest_difference_between_any_two_deposits():
    row = {"runs": {"0.3": {"extent": 9.2, "height": -0.3}, "0.5": {"extent": -19.9, "height": 0.1}}}
    assert obstacle_friction.span(row) == pytest.approx(29.1)
    assert obstacle_friction.span({"runs": {"0.3": {"extent": 2.0, "height": 3.0}}}) == 3.0
