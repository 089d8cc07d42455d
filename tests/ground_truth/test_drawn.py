"""drawn.json: gns generate records every value each trajectory drew, so an inversion's answer can be checked."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scene_builders import mixed

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.drawn import DRAWN_FILE, read_drawn, true_property, true_velocity
from gns_framework.ground_truth.generate import generate_dataset, trajectory_seeds
from gns_framework.ground_truth.sampling import sample_scene
from gns_framework.ground_truth.scene_spec import parse_scene


def drawing_scene() -> dict:
    raw = mixed(frames=4)
    raw["domain"].update(
        extent=[{"range": [0.45, 0.5]}, 0.5],
        walls={"x_max": {"one_of": [0.1, "no_slip"]}, "y_min": {"range": [0.2, 0.6]}},
    )
    raw["blocks"].append(
        {
            "material": "sand",
            "position": [0.1, 0.3],
            "size": [0.05, 0.05],
            "properties": {"friction": {"range": [0.5, 0.9]}},
        }
    )  # drawn once per trajectory
    raw["obstacles"][0]["friction"] = {"range": [0.1, 0.3]}
    raw["obstacles"][0]["size"] = [{"range": [0.08, 0.12]}, 0.04]
    return raw


@pytest.fixture(scope="module")
def generated(tmp_path_factory, sim_registry):
    scene = parse_scene(drawing_scene())
    simulator = build_ground_truth_simulator(scene, sim_registry)
    out = tmp_path_factory.mktemp("drawn")
    generate_dataset(
        scene, simulator, out, sim_registry.get("dataset", "safe"), {"train": 2, "valid": 1, "test": 1}, progress=False
    )
    return scene, out


def test_every_trajectory_records_what_it_drew(generated, sim_registry, materials):
    scene, out = generated
    drawn = json.loads((out / DRAWN_FILE).read_text())["trajectories"]
    cls = sim_registry.get("dataset", "safe")
    keys = [t.key for split in ("train", "valid", "test") for t in cls(cls.Params(), out).split(split)]
    assert list(drawn) == keys == [f"seed_{s}" for s in trajectory_seeds(scene.seed, 4)]
    for key, seed in zip(keys, trajectory_seeds(scene.seed, 4), strict=True):
        sample, record = sample_scene(scene, seed), drawn[key]
        assert set(record) == {"domain", "blocks[0]", "blocks[1]", "blocks[2]", "blocks[3]", "obstacles[0]"}
        np.testing.assert_allclose(record["domain"]["bounds"], sample.bounds, atol=1e-6)
        assert record["domain"]["extent"][0] == pytest.approx(sample.bounds[0, 1] - sample.bounds[0, 0], abs=1e-6)
        faces = record["domain"]["walls"]
        np.testing.assert_allclose(
            [[faces[f]["friction"], float(faces[f]["no_slip"])] for f in ("x_min", "x_max", "y_min", "y_max")],
            sample.walls,
            atol=1e-6,
        )
        water, sand, goop, sand2 = sample.blocks
        assert record["blocks[0]"]["size"] == pytest.approx(water.size.tolist())
        assert record["blocks[1]"]["position"] == pytest.approx(sand.lower.tolist())
        assert record["blocks[3]"]["friction"] == pytest.approx(float(sand2.values["friction"][0]))
        assert record["blocks[1]"]["particle_type"] == materials["sand"].particle_type
        assert record["blocks[2]"]["velocity"] == pytest.approx(goop.velocity.tolist())
        per_particle = record["blocks[1]"]["friction"]
        assert per_particle["min"] < per_particle["mean"] < per_particle["max"]
        assert record["obstacles[0]"]["friction"] == pytest.approx(sample.obstacles[0].friction)
        assert record["obstacles[0]"]["size"] == pytest.approx(sample.obstacles[0].size.tolist())
        assert true_velocity(record, materials["goop"].particle_type) == pytest.approx(goop.velocity.tolist())
        # Two sand blocks, one drawn per particle: no single true friction of the sand.
        assert true_property(record, "friction", materials["sand"].particle_type) is None
        alone = {k: v for k, v in record.items() if k != "blocks[1]"}
        assert true_property(alone, "friction", materials["sand"].particle_type) == pytest.approx(
            float(sand2.values["friction"][0])
        )
    # Frictions, velocities and the domain really vary between trajectories: they were drawn.
    assert len({drawn[k]["blocks[3]"]["friction"] for k in keys}) == 4
    assert len({drawn[k]["obstacles[0]"]["friction"] for k in keys}) == 4


def test_a_dataset_without_drawn_json_is_drawn_again_from_its_provenance(generated, tmp_path, materials):
    _, out = generated
    recorded = json.loads((out / DRAWN_FILE).read_text())["trajectories"]
    for name in ("metadata.json",):
        (tmp_path / name).write_bytes((out / name).read_bytes())
    key = next(iter(recorded))
    assert read_drawn(tmp_path, key, materials) == recorded[key]
    assert read_drawn(tmp_path, "trajectory_00000", materials) is None  # no seed in the key: the truth is unknown
    (tmp_path / "metadata.json").write_text("{}")
    assert read_drawn(tmp_path, key, materials) is None
