"""The shipped pretrained model (models/sand2d_fast.pt) loads on a CPU and works on collapses it never saw."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from cli_runner import gns

from gns_framework.assembly.trained import load_trained

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "sand2d_fast.pt"
SCENE = REPO / "scenes" / "demo_sand_2d.yaml"


def test_the_shipped_model_is_small_and_loads_on_the_cpu(registry):
    assert MODEL.stat().st_size < 5e6
    loaded = load_trained(MODEL, registry, "cpu")
    assert loaded.recipe.name == "sand2d-fast" and loaded.recipe.dataset.frame_stride == 2
    assert all(p.device.type == "cpu" for p in loaded.simulator.parameters())


@pytest.fixture(scope="module")
def unseen_collapse(tmp_path_factory) -> Path:
    """One collapse of the demo scene from a seed the model never trained or was evaluated on."""
    out = tmp_path_factory.mktemp("unseen") / "data"
    result = gns(
        "generate",
        str(SCENE),
        "--seed",
        "99",
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


@pytest.mark.parametrize("simulator", [False, True])
def test_gns_evaluate_runs_the_shipped_model_on_new_data(unseen_collapse, tmp_path, simulator):
    extra = ["--grid-scales", "1"] if simulator else ["--no-simulator"]
    result = gns(
        "evaluate",
        str(MODEL),
        "--dataset",
        str(unseen_collapse),
        "--out",
        str(tmp_path),
        "--repeats",
        "1",
        "--warmup",
        "0",
        *extra,
    )
    assert result.returncode == 0, result.stderr
    with (tmp_path / "report.csv").open() as handle:
        rows = {row["name"]: row for row in csv.DictReader(handle)}
    learned = rows["sand2d-fast"]
    assert float(learned["diverged"]) == 0
    # The model card's bound on held-out collapses: no runout error above 15 %.
    assert float(learned["runout_error_pct"]) < 15
    if simulator:
        reference = next(row for row in rows.values() if row["reference"] == "True")
        assert float(reference["sinkhorn_final_pct"]) < 1e-3, "the reference re-simulates the ground truth"
