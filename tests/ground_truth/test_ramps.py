"""The ramps scene family (issue 19): boundary particles recorded like DeepMind's ramps, and a dataset gns train
takes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from tiny import tiny_recipe_mapping

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.cli import generate as generate_command
from gns_framework.cli import main
from gns_framework.ground_truth.sampling import sample_scene
from gns_framework.ground_truth.scene_spec import load_scene
from gns_framework.io.checkpoint import latest_good_checkpoint

SCENES = Path(__file__).resolve().parents[2] / "scenes"
RIGID = 3


def shortened(name: str, frames: int):
    scene = load_scene(SCENES / f"{name}.yaml")
    return scene.model_copy(update={"time": scene.time.model_copy(update={"frames": frames})})


@pytest.mark.parametrize("name", ["sand_ramps_2d", "water_ramps_2d", "sand_ramps_3d"])
def test_ramps_are_static_boundary_particles_drawn_anew_per_trajectory(name, sim_registry):
    scene = shortened(name, 4)
    simulator = build_ground_truth_simulator(scene, sim_registry, name)
    first, second = simulator.simulate(scene, 1), simulator.simulate(scene, 2)
    for trajectory in (first, second):
        ramp = trajectory.particle_type == RIGID
        assert ramp.sum() > 100
        assert np.array_equal(trajectory.position[0, ramp], trajectory.position[-1, ramp])
        assert (trajectory.particle_type[~ramp] != RIGID).all() and (~ramp).sum() > 100
    ramps = [sample_scene(scene, seed).obstacles for seed in (1, 2)]
    assert all(a.angle != b.angle and not np.array_equal(a.lower, b.lower) for a, b in zip(*ramps, strict=True))


def test_generated_ramps_dataset_trains(sim_registry, monkeypatch, tmp_path):
    monkeypatch.setattr(generate_command, "load_registry", lambda: sim_registry)
    scene = shortened("sand_ramps_2d", 12)
    scene_file = tmp_path / "ramps.yaml"
    scene_file.write_text(yaml.safe_dump(scene.model_dump(mode="json", exclude_none=True)))
    data = tmp_path / "data"
    assert (
        main(
            [
                "generate",
                str(scene_file),
                "--trajectories",
                "3",
                "--valid",
                "1",
                "--test",
                "0",
                "--out",
                str(data),
                "--no-progress",
            ]
        )
        == 0
    )
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(data, run_dir=tmp_path / "run")))
    assert main(["train", str(recipe), "--steps", "3", "--no-progress"]) == 0
    found = latest_good_checkpoint(tmp_path / "run" / "checkpoints")
    assert found is not None
    _, state = found
    assert state["step"] == 3
    # The ramps are the model's kinematic (boundary) particles: positions given, never predicted.
    assert state["scene"]["kinematic_types"] == [RIGID]
