"""``gns generate``: seeded splits, metadata from the data, reproducible, cached."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from scene_builders import column_collapse, mixed

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.cli import generate as generate_command
from gns_framework.cli import main
from gns_framework.data.metadata import compute_statistics, load_metadata
from gns_framework.data.particle_spacing import suggest_connectivity_radius
from gns_framework.ground_truth.generate import generate_dataset, trajectory_seeds
from gns_framework.ground_truth.scene_spec import parse_scene


def test_trajectory_seeds_do_not_depend_on_how_many_are_drawn():
    assert trajectory_seeds(7, 5)[:3] == trajectory_seeds(7, 3)
    assert len(set(trajectory_seeds(7, 50))) == 50
    assert trajectory_seeds(7, 3) != trajectory_seeds(8, 3)


@pytest.fixture(scope="module")
def generated(tmp_path_factory, sim_registry):
    scene = parse_scene(mixed(frames=12))
    simulator = build_ground_truth_simulator(scene, sim_registry)
    out = tmp_path_factory.mktemp("generated")
    metadata = generate_dataset(
        scene, simulator, out, sim_registry.get("dataset", "safe"), {"train": 2, "valid": 1, "test": 1}, progress=False
    )
    return scene, simulator, out, metadata


def load_split(registry, path, split):
    cls = registry.get("dataset", "safe")
    return list(cls(cls.Params(), path).split(split))


def test_dataset_has_splits_and_metadata_from_its_train_split(generated, sim_registry):
    scene, _, out, metadata = generated
    train = load_split(sim_registry, out, "train")
    assert [len(load_split(sim_registry, out, s)) for s in ("train", "valid", "test")] == [2, 1, 1]
    assert load_metadata(out) == metadata
    stats = compute_statistics(train, sim_registry.kinematic_types())
    for key, values in stats.items():
        assert getattr(metadata, key) == pytest.approx(values)
    assert metadata.sequence_length == scene.time.frames == train[0].num_steps
    assert metadata.dt == scene.time.frame_dt
    assert metadata.bounds == [tuple(b) for b in scene.domain.bounds]
    assert metadata.default_connectivity_radius == suggest_connectivity_radius(train)
    assert metadata.model_extra["material_properties"] == ["friction"]


def test_generation_is_reproducible_and_splits_differ(generated, sim_registry, tmp_path):
    scene, simulator, out, _ = generated
    again = tmp_path / "again"
    generate_dataset(
        scene,
        simulator,
        again,
        sim_registry.get("dataset", "safe"),
        {"train": 2, "valid": 1, "test": 1},
        progress=False,
    )
    for split in ("train", "valid", "test"):
        for a, b in zip(load_split(sim_registry, out, split), load_split(sim_registry, again, split), strict=True):
            assert a.position.tobytes() == b.position.tobytes()
    train = load_split(sim_registry, out, "train")
    assert train[0].key != train[1].key
    assert train[0].position.shape != train[1].position.shape or not np.array_equal(
        train[0].position, train[1].position
    )


def test_scene_without_properties_writes_none(sim_registry, tmp_path):
    scene = parse_scene(column_collapse(0.05, 0.05, 0.6, frames=4))
    metadata = generate_dataset(
        scene,
        build_ground_truth_simulator(scene, sim_registry),
        tmp_path,
        sim_registry.get("dataset", "safe"),
        {"train": 1},
        progress=False,
    )
    assert load_split(sim_registry, tmp_path, "train")[0].material_property is None
    assert "material_properties" not in metadata.model_extra


@pytest.fixture
def cli_registry(sim_registry, monkeypatch):
    monkeypatch.setattr(generate_command, "load_registry", lambda: sim_registry)


def test_gns_generate_writes_then_reuses_a_dataset(cli_registry, tmp_path, capsys):
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(yaml.safe_dump(mixed(frames=6)))
    out = tmp_path / "data"
    args = ["generate", str(scene_file), "--trajectories", "3", "--out", str(out), "--no-progress"]
    assert main(args) == 0
    assert "wrote 3 trajectories (train 1, valid 1, test 1)" in capsys.readouterr().out
    written = (out / "train.npz").stat().st_mtime_ns
    assert main(args) == 0
    assert "already holds this dataset" in capsys.readouterr().out
    assert (out / "train.npz").stat().st_mtime_ns == written
    assert main([*args, "--valid", "0", "--test", "0"]) == 0
    assert json.loads((out / "metadata.json").read_text())["generated_from"]["trajectories"]["train"] == 3


def test_gns_generate_reports_scene_problems(cli_registry, tmp_path, capsys):
    raw = mixed()
    raw["blocks"][0]["material"] = "lava"
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(raw))
    args = ["generate", str(tmp_path / "scene.yaml"), "--trajectories", "1", "--out", str(tmp_path / "d")]
    assert main(args) == 2
    assert "blocks[0].material: unknown material 'lava'" in capsys.readouterr().err


def test_split_counts_hold_what_was_asked_for_and_may_hold_out_everything():
    assert generate_command.split_counts(10, None, None) == {"train": 8, "valid": 1, "test": 1}
    assert generate_command.split_counts(2, None, None) == {"train": 2, "valid": 0, "test": 0}
    assert generate_command.split_counts(3, 0, 3) == {"train": 0, "valid": 0, "test": 3}
    with pytest.raises(Exception, match="fewer than the 2 valid and 2 test"):
        generate_command.split_counts(3, 2, 2)


def test_a_test_only_dataset_takes_its_statistics_from_its_own_splits(sim_registry, tmp_path):
    """Held-out seeds for a model trained elsewhere: no train split, and the metadata says where its statistics came
    from."""
    scene = parse_scene(mixed(frames=8))
    simulator = build_ground_truth_simulator(scene, sim_registry)
    cls = sim_registry.get("dataset", "safe")
    metadata = generate_dataset(scene, simulator, tmp_path, cls, {"train": 0, "valid": 0, "test": 2}, progress=False)
    test = load_split(sim_registry, tmp_path, "test")
    assert len(test) == 2 and not (tmp_path / "train.npz").exists()
    assert metadata.statistics_from == ["test"]
    assert metadata.vel_std == pytest.approx(compute_statistics(test, sim_registry.kinematic_types())["vel_std"])


def test_gns_generate_seed_gives_trajectories_the_file_seed_never_does(cli_registry, tmp_path, capsys):
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(yaml.safe_dump(mixed(frames=6)))
    common = ["generate", str(scene_file), "--trajectories", "3", "--no-progress"]
    assert main([*common, "--out", str(tmp_path / "file_seed")]) == 0
    assert main([*common, "--out", str(tmp_path / "seed_5"), "--seed", "5"]) == 0
    provenance = json.loads((tmp_path / "seed_5" / "metadata.json").read_text())["generated_from"]
    assert provenance["scene"]["seed"] == 5
    with np.load(tmp_path / "file_seed" / "test.npz") as a, np.load(tmp_path / "seed_5" / "test.npz") as b:
        first, other = (next(k for k in archive.files if k.endswith("position")) for archive in (a, b))
        assert first != other and not np.array_equal(a[first], b[other])
    with pytest.raises(SystemExit) as exited:
        main([*common, "--out", str(tmp_path / "bad"), "--seed", "-1"])
    assert exited.value.code == 2
    assert "--seed: must be >= 0, got -1" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
