"""The shipped general sand model (models/sand2d_general.pt): its envelope travels with it, it refuses
data outside it, and it holds on a canonical scene it never trained on, in a box with slip side walls."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from cli_runner import gns

from gns_framework.assembly.trained import load_trained

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "sand2d_general.pt"


def test_the_envelope_it_records_is_the_card_s(registry):
    assert MODEL.stat().st_size < 12e6
    loaded = load_trained(MODEL, registry, "cpu")
    envelope = loaded.envelope.to_dict()
    assert envelope["dim"] == 2 and envelope["frame_stride"] == 2 and envelope["step_dt"] == pytest.approx(0.01)
    assert envelope["extent"] == [[0.75, 2.0], [0.5, 1.0]]
    assert envelope["materials"] == {"3": "rigid", "6": "sand"}
    low, high = envelope["properties"]["friction"]
    assert 0.5 <= low < 0.51 and 0.89 < high <= 0.9
    assert envelope["walls"]["x_min"]["slip"] and not envelope["walls"]["y_min"]["slip"]


@pytest.fixture(scope="module")
def canonical(tmp_path_factory) -> Path:
    """One case of scenes/canonical/slip_side_walls.yaml, which no training or validation scene is."""
    out = tmp_path_factory.mktemp("canonical") / "data"
    result = gns(
        "generate",
        str(REPO / "scenes" / "canonical" / "slip_side_walls.yaml"),
        "--trajectories",
        "2",
        "--valid",
        "0",
        "--test",
        "1",
        "--out",
        str(out),
        "--no-progress",
    )
    assert result.returncode == 0, result.stderr
    return out


def test_it_holds_on_a_canonical_scene(canonical, tmp_path):
    result = gns(
        "evaluate",
        str(MODEL),
        "--dataset",
        str(canonical),
        "--out",
        str(tmp_path),
        "--repeats",
        "1",
        "--warmup",
        "0",
        "--no-simulator",
    )
    assert result.returncode == 0, result.stderr
    with (tmp_path / "report.csv").open() as handle:
        learned = next(row for row in csv.DictReader(handle) if row["reference"] != "True")
    assert float(learned["diverged"]) == 0
    # The card's goal for the canonical scenes: final extent and pile height within 15 % of the MPM's.
    assert float(learned["extent_error_pct"]) < 15 and float(learned["height_error_pct"]) < 15


def test_data_outside_the_envelope_is_refused_naming_what(tmp_path):
    """The demo's sand at another spacing (grid 64 instead of 48): refused, naming the spacing and its range."""
    scene = (REPO / "scenes" / "demo_sand_2d.yaml").read_text().replace("grid: 48", "grid: 64")
    assert "grid: 64" in scene
    (tmp_path / "fine.yaml").write_text(scene)
    out = tmp_path / "fine"
    made = gns(
        "generate",
        str(tmp_path / "fine.yaml"),
        "--trajectories",
        "2",
        "--valid",
        "0",
        "--test",
        "1",
        "--out",
        str(out),
        "--no-progress",
    )
    assert made.returncode == 0, made.stderr
    result = gns("rollout", str(MODEL), "--dataset", str(out), "--out", str(tmp_path / "rollouts"))
    assert result.returncode != 0
    assert (
        "nearest-neighbour distance (median)" in result.stderr
        and "trained" in result.stderr
        and "--outside-envelope" in result.stderr
    )
    assert not (tmp_path / "rollouts").exists() or not any((tmp_path / "rollouts").iterdir())
