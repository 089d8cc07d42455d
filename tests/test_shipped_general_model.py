"""The shipped general sand models (models/sand2d_general.pt, and sand2d_general_fast.pt with its 20 ms step):
the envelope travels with each, each refuses data outside it, and each holds on a canonical scene it never trained
on, in a box with slip side walls."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from cli_runner import gns

from gns_framework.assembly.trained import load_trained

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "sand2d_general.pt"
FAST = REPO / "models" / "sand2d_general_fast.pt"
STRIDES = {MODEL: 2, FAST: 4}
"""Stored frames (of 5 ms) per learned step of each model."""
models = pytest.mark.parametrize("model", [MODEL, FAST], ids=lambda path: path.stem)


@models
def test_the_envelope_it_records_is_the_card_s(registry, model):
    assert model.stat().st_size < 12e6
    loaded = load_trained(model, registry, "cpu")
    envelope = loaded.envelope.to_dict()
    stride = STRIDES[model]
    assert envelope["dim"] == 2 and envelope["frame_stride"] == stride
    assert envelope["step_dt"] == pytest.approx(0.005 * stride)
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


@models
def test_it_holds_on_a_canonical_scene(canonical, tmp_path, model):
    result = gns(
        "evaluate",
        str(model),
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
    with (tmp_path / "cases.csv").open() as handle:
        (case,) = list(csv.DictReader(handle))
    # The fast model carries a deposit warning and scores its rollout with it; the other model has none.
    assert bool(case.get("deposit_warning_score")) == (model == FAST)


def test_the_fast_model_carries_the_deposit_warning_the_card_measures(registry):
    warning = load_trained(FAST, registry, "cpu").deposit_warning
    assert warning is not None and warning.error_pct == 15.0 and warning.friction_property == "friction"
    assert "250 training scenes (20 over 15 %)" in warning.fitted_on
    assert "on 104 scenes it never saw it flagged 92% of 12 over 15 % and 20% of 92 others" in warning.fitted_on


@models
def test_data_outside_the_envelope_is_refused_naming_what(tmp_path, model):
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
    result = gns("rollout", str(model), "--dataset", str(out), "--out", str(tmp_path / "rollouts"))
    assert result.returncode != 0
    assert (
        "nearest-neighbour distance (median)" in result.stderr
        and "trained" in result.stderr
        and "--outside-envelope" in result.stderr
    )
    assert not (tmp_path / "rollouts").exists() or not any((tmp_path / "rollouts").iterdir())
