"""Every layout round-trips through ``gns convert``; loading validates and names file, trajectory, field."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from synthetic import soft_sphere_trajectory, synthetic_metadata
from tiny import tiny_recipe_mapping

from gns_framework.cli import main
from gns_framework.config.recipe import validate_recipe
from gns_framework.contracts import Material
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError
from gns_framework.hookspecs import hookimpl
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer

LAYOUTS = ["safe", "npz", "tfrecord", "lagrangebench"]


def write_source(path, registry, with_context: bool):
    """A small safe dataset with kinematic particles, a material property and (optionally) a step context."""
    splits = {}
    for split, seeds in {"train": (0, 1), "valid": (2,), "test": (3,)}.items():
        splits[split] = []
        for seed in seeds:
            traj = soft_sphere_trajectory(
                seed,
                frames=8,
                block=3,
                particle_types=(5, 6),
                kinematic_floor=True,
                with_property=True,
                key=f"{split}_{seed}",
            )
            context = np.linspace(0, 1, traj.num_steps, dtype=np.float32)[:, None] if with_context else None
            splits[split].append(
                Trajectory(traj.position, traj.particle_type, traj.material_property, context, traj.key)
            )
    registry.get("dataset", "safe").write(path, synthetic_metadata(splits["train"], 2), splits)
    return path, splits


@pytest.fixture(scope="module")
def source(tmp_path_factory, registry):
    return write_source(tmp_path_factory.mktemp("source"), registry, with_context=True)


@pytest.fixture(scope="module")
def source_without_context(tmp_path_factory, registry):
    """geoelements' tuples have no place for a step context."""
    return write_source(tmp_path_factory.mktemp("source"), registry, with_context=False)


def convert(src, source_layout, target_layout, out) -> None:
    assert main(["convert", str(src), "--from", source_layout, "--to", target_layout, "--out", str(out)]) == 0


def load(registry, layout, path):
    cls = registry.get("dataset", layout)
    dataset = cls(cls.Params(), path)
    return dataset.metadata(), {name: list(dataset.split(name)) for name in dataset.splits()}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_round_trip_through_every_layout(layout, source, source_without_context, registry, tmp_path):
    src, original = source_without_context if layout == "npz" else source
    convert(src, "safe", layout, tmp_path / layout)
    convert(tmp_path / layout, layout, "safe", tmp_path / "back")
    metadata, splits = load(registry, "safe", tmp_path / "back")
    expected_metadata, _ = load(registry, "safe", src)
    for field in (
        "bounds",
        "sequence_length",
        "default_connectivity_radius",
        "dim",
        "dt",
        "vel_mean",
        "vel_std",
        "acc_mean",
        "acc_std",
    ):
        assert getattr(metadata, field) == getattr(expected_metadata, field), field
    assert {k: len(v) for k, v in splits.items()} == {"train": 2, "valid": 1, "test": 1}
    for name, trajectories in original.items():
        for before, after in zip(trajectories, splits[name], strict=True):
            np.testing.assert_array_equal(before.position, after.position)
            np.testing.assert_array_equal(before.particle_type, after.particle_type)
            np.testing.assert_array_equal(before.material_property, after.material_property)
            np.testing.assert_array_equal(before.step_context, after.step_context)


def test_tfrecord_metadata_counts_steps_like_deepmind(source, tmp_path):
    src, original = source
    convert(src, "safe", "tfrecord", tmp_path / "tf")
    stored = json.loads((tmp_path / "tf" / "metadata.json").read_text())
    assert stored["sequence_length"] == original["train"][0].num_steps - 1


def test_lagrangebench_files_look_like_lagrangebench(source, tmp_path):
    src, original = source
    convert(src, "safe", "lagrangebench", tmp_path / "lb")
    stored = json.loads((tmp_path / "lb" / "metadata.json").read_text())
    assert stored["periodic_boundary_conditions"] == [False, False]
    # LagrangeBench counts steps between frames, per split, and has no plain sequence_length.
    assert stored["sequence_length_train"] == original["train"][0].num_steps - 1
    assert stored["num_trajs_train"] == 2 and "sequence_length" not in stored
    assert stored["num_particles_max"] == max(t.num_particles for t in original["train"])
    with h5py.File(tmp_path / "lb" / "train.h5", "r") as handle:
        assert sorted(handle) == ["00000", "00001"]
        assert handle["00000/position"].shape == original["train"][0].position.shape


def test_lagrangebench_solver_dt_and_write_every_give_the_frame_dt(registry, tmp_path):
    traj = soft_sphere_trajectory(0, frames=6, block=2)
    with h5py.File(tmp_path / "train.h5", "w") as handle:
        handle["00000/position"] = traj.position.astype(np.float64)
        handle["00000/particle_type"] = np.zeros(traj.num_particles, dtype=np.int32)
    raw = {
        "dim": 2,
        "dt": 0.0005,
        "write_every": 100,
        "bounds": [[0, 1], [0, 1]],
        "default_connectivity_radius": 0.029,
        "vel_mean": [0, 0],
        "vel_std": [1, 1],
        "acc_mean": [0, 0],
        "acc_std": [1, 1],
        "periodic_boundary_conditions": [True, True],
    }
    (tmp_path / "metadata.json").write_text(json.dumps(raw))
    metadata, splits = load(registry, "lagrangebench", tmp_path)
    assert metadata.dt == pytest.approx(0.05)
    assert metadata.sequence_length == 6
    assert splits["train"][0].position.dtype == np.float32


def test_sequence_length_disagreeing_with_metadata_names_file_trajectory_and_field(source, registry, tmp_path):
    src, _ = source
    convert(src, "safe", "tfrecord", tmp_path / "tf")
    stored = json.loads((tmp_path / "tf" / "metadata.json").read_text())
    stored["sequence_length"] += 3
    (tmp_path / "tf" / "metadata.json").write_text(json.dumps(stored))
    with pytest.raises(DatasetError, match=r"train\.tfrecord: trajectory 'train_0': position: has 8 frames"):
        load(registry, "tfrecord", tmp_path / "tf")


def test_negative_particle_type_is_located(registry, tmp_path):
    traj = soft_sphere_trajectory(0, frames=5, block=2)
    bad = Trajectory(traj.position, np.full(traj.num_particles, -1), key="odd")
    registry.get("dataset", "lagrangebench").write(tmp_path, synthetic_metadata([traj], 2), {"train": [bad]})
    with pytest.raises(DatasetError, match=r"train\.h5: trajectory 'odd': particle_type: ids must be >= 0"):
        load(registry, "lagrangebench", tmp_path)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_any_type_id_a_material_may_take_is_read_back(layout, registry, tmp_path):
    """A third-party material takes id 9, or 42: the readers accept what the writers wrote."""
    traj = soft_sphere_trajectory(0, frames=5, block=2, particle_types=(9, 42), key="0")
    registry.get("dataset", layout).write(tmp_path, synthetic_metadata([traj], 2), {"train": [traj]})
    _, splits = load(registry, layout, tmp_path)
    np.testing.assert_array_equal(splits["train"][0].particle_type, traj.particle_type)


def test_non_finite_positions_are_located(registry, tmp_path):
    traj = soft_sphere_trajectory(0, frames=5, block=2)
    position = traj.position.copy()
    position[3, 1, 0] = np.inf
    registry.get("dataset", "tfrecord").write(
        tmp_path, synthetic_metadata([traj], 2), {"valid": [Trajectory(position, traj.particle_type, key="v")]}
    )
    with pytest.raises(DatasetError, match=r"valid\.tfrecord: trajectory 'v': position: non-finite value at frame 3"):
        load(registry, "tfrecord", tmp_path)


def test_dimension_disagreeing_with_metadata_is_located(registry, tmp_path):
    flat = soft_sphere_trajectory(0, frames=5, block=2)
    metadata = synthetic_metadata([soft_sphere_trajectory(0, dim=3, frames=5, block=2)], 3)
    registry.get("dataset", "lagrangebench").write(tmp_path, metadata, {"train": [flat]})
    with pytest.raises(DatasetError, match=r"position: has d = 2 but metadata says dim = 3"):
        load(registry, "lagrangebench", tmp_path)


def test_a_record_that_is_not_a_trajectory_is_located(registry, tmp_path):
    from gns_builtins.datasets._formats.tfrecord_format import Feature, SequenceExample, write_records

    traj = soft_sphere_trajectory(0, frames=5, block=2)
    registry.get("dataset", "tfrecord").write(tmp_path, synthetic_metadata([traj], 2), {"train": [traj]})
    example = SequenceExample(
        {"particle_type": Feature("bytes", [np.zeros(3, "<i8").tobytes()])},
        {"position": [Feature("bytes", [np.zeros(5, "<f4").tobytes()])] * 5},
    )
    write_records(tmp_path / "train.tfrecord", [example.serialize()])
    with pytest.raises(DatasetError, match=r"trajectory 0: position: expected 3 x 2 = 6 floats per frame, got \[5\]"):
        load(registry, "tfrecord", tmp_path)


def test_convert_refuses_a_read_only_or_unknown_layout(source, tmp_path, capsys):
    src, _ = source
    assert main(["convert", str(src), "--from", "safe", "--to", "nope", "--out", str(tmp_path / "x")]) == 2
    assert "--to nope: unknown dataset 'nope'" in capsys.readouterr().err
    assert main(["convert", str(src), "--from", "saf", "--to", "npz", "--out", str(tmp_path / "x")]) == 2
    assert "--from saf: unknown dataset 'saf' (did you mean 'safe'?)" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


class _Ochre(Material):
    """A third-party material: the next free type id after the built-ins and the example clay is 9."""

    name = "ochre"
    particle_type = 9
    description = "test material"
    constitutive_model = "von_mises"


class _OchrePlugin:
    @staticmethod
    @hookimpl
    def gns_materials():
        return [_Ochre]


@pytest.mark.parametrize("layout", ["tfrecord", "lagrangebench"])
def test_a_material_of_type_9_converts_and_trains(layout, tmp_path):
    registry = load_registry(plugins=[("ochre", _OchrePlugin)])
    trajectories = [
        soft_sphere_trajectory(seed, frames=10, block=3, particle_types=(9,), kinematic_floor=True, key=str(seed))
        for seed in range(2)
    ]
    registry.get("dataset", layout).write(
        tmp_path / "src", synthetic_metadata(trajectories, 2), {"train": trajectories[:1], "valid": trajectories[1:]}
    )
    convert(tmp_path / "src", layout, layout, tmp_path / "out")
    raw = tiny_recipe_mapping(tmp_path / "out")
    raw["dataset"]["name"] = layout
    trainer = Trainer(validate_recipe(raw, registry), registry, run_dir=tmp_path / "run", progress=False)
    assert trainer.data.setup.particle_types == (3, 9)
    assert np.isfinite(trainer.train(1)).all()
    trainer.close()


def _lagrangebench_tgv(folder, frames: int = 10, side: int = 6):
    """A 2D Taylor-Green vortex as LagrangeBench stores it: fluid type 0, periodic in x and y, HDF5 per split."""
    folder.mkdir()
    spacing = 1.0 / side
    grid = (np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2) + 0.5) * spacing
    steps = np.arange(frames)[:, None, None]
    # Each particle moves with the vortex's velocity at its start, (sin 2 pi x cos 2 pi y, -cos 2 pi x sin 2 pi y),
    # 2 mm a frame at most, wrapped into [0, 1) as a periodic box keeps it.
    flow = np.stack(
        [
            np.sin(2 * np.pi * grid[:, 0]) * np.cos(2 * np.pi * grid[:, 1]),
            -np.cos(2 * np.pi * grid[:, 0]) * np.sin(2 * np.pi * grid[:, 1]),
        ],
        -1,
    )
    position = np.mod(grid[None] + 0.002 * steps * flow[None], 1.0)
    for split in ("train", "valid", "test"):
        with h5py.File(folder / f"{split}.h5", "w") as handle:
            handle["00000/position"] = position.astype(np.float32)
            handle["00000/particle_type"] = np.zeros(side * side, dtype=np.int32)
    velocity = np.diff(position, axis=0)
    raw = {
        "case": "TGV",
        "dim": 2,
        "dt": 0.0004,
        "write_every": 25,
        "bounds": [[0, 1], [0, 1]],
        "default_connectivity_radius": 1.5 * spacing,
        "periodic_boundary_conditions": [True, True, True],
        "sequence_length_train": frames - 1,
        "sequence_length_test": frames - 1,
        "vel_mean": [0, 0],
        "vel_std": np.abs(velocity).reshape(-1, 2).std(0).tolist(),
        "acc_mean": [0, 0],
        "acc_std": [1e-4, 1e-4],
    }
    (folder / "metadata.json").write_text(json.dumps(raw))


def test_lagrangebench_periodic_data_converts_with_its_types_mapped_and_trains_the_periodic_recipe(tmp_path):
    """recipes/swaps/periodic_radius.yaml's documented data path: LagrangeBench's TGV, fluid 0 mapped to water 5."""
    from pathlib import Path

    import yaml

    _lagrangebench_tgv(tmp_path / "tgv")
    assert (
        main(
            [
                "convert",
                str(tmp_path / "tgv"),
                "--from",
                "lagrangebench",
                "--to",
                "safe",
                "--out",
                str(tmp_path / "periodic2d"),
                "--map-types",
                "0=5",
            ]
        )
        == 0
    )
    registry = load_registry()
    metadata, splits = load(registry, "safe", tmp_path / "periodic2d")
    assert metadata.periodic_boundary_conditions == [True, True]
    assert all((t.particle_type == 5).all() for trajectories in splits.values() for t in trajectories)
    recipe_file = Path(__file__).resolve().parents[2] / "recipes" / "swaps" / "periodic_radius.yaml"
    raw = yaml.safe_load(recipe_file.read_text())
    assert raw["dataset"]["path"] == "data/periodic2d", "the folder the recipe's comment tells the user to convert into"
    raw["dataset"]["path"] = str(tmp_path / "periodic2d")
    raw["output_dir"] = str(tmp_path / "run")
    trainer = Trainer(validate_recipe(raw, registry), registry, progress=False)
    assert trainer.data.setup.periodic_dims == (0, 1) and trainer.data.setup.particle_types == (5,)
    assert np.isfinite(trainer.train(1)).all()
    trainer.close()


@pytest.mark.parametrize("text", ["0", "0=x", "0=5,0=6", "-1=5"])
def test_a_bad_type_map_is_refused_with_the_expected_form(text, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_code:
        main(
            [
                "convert",
                str(tmp_path),
                "--from",
                "lagrangebench",
                "--to",
                "safe",
                "--out",
                str(tmp_path / "o"),
                "--map-types",
                text,
            ]
        )
    assert exit_code.value.code == 2
    assert "--map-types" in capsys.readouterr().err
