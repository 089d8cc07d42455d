"""Data never runs code: geoelements pickles of arrays read safely, anything more only by a per-command grant."""

from __future__ import annotations

import io
import json
import pickle
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hostile import MEMBER, write_hostile_dataset
from synthetic import soft_sphere_trajectory, synthetic_metadata
from tiny import tiny_recipe, tiny_recipe_mapping, tiny_trainer

from gns_framework.cli import build_parser, main
from gns_framework.data.array_pickle import RefusedGlobal, read_npy_object_array
from gns_framework.errors import DatasetError
from gns_framework.io.checkpoint import save_checkpoint

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def numpy1_npy(item: np.ndarray) -> bytes:
    """``item`` as NumPy 1.x's ``np.save`` writes it: format 1.0, a protocol-3 pickle naming ``numpy.core``."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(item))
    payload = pickle.dumps(item, protocol=3).replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    assert b"cnumpy.core.multiarray\n_reconstruct" in payload and b"_core" not in payload
    return header.getvalue() + payload


def write_npz_as_numpy1(path: Path, members: dict[str, np.ndarray]) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        for key, item in members.items():
            archive.writestr(f"{key}.npy", numpy1_npy(item))


def object_array(*fields) -> np.ndarray:
    item = np.empty(len(fields), dtype=object)
    for i, field in enumerate(fields):
        item[i] = field
    return item


def metadata_of(dataset: Path) -> dict:
    return json.loads((dataset / "metadata.json").read_text())


def safe_copy_of(source: Path, registry) -> dict[str, list]:
    cls = registry.get("dataset", "safe")
    dataset = cls(cls.Params(), source)
    return {split: list(dataset.split(split)) for split in dataset.splits()}


@pytest.fixture(scope="module")
def trajectories():
    return [
        soft_sphere_trajectory(seed, frames=8, block=3, particle_types=(6,), kinematic_floor=True, with_property=True,
                               key=f"simulation_trajectory_{seed}")
        for seed in range(2)
    ]


@pytest.mark.parametrize("numpy_version", ["2.x", "1.x"])
def test_geoelements_files_as_numpy_writes_them_read_without_opt_in(numpy_version, trajectories, tmp_path, registry):
    """The pickles of NumPy 2.x (protocol 4, ``numpy._core``) and 1.x (protocol 3, ``numpy.core``) hold only arrays."""
    source = tmp_path / "geoelements"
    registry.get("dataset", "npz").write(source, synthetic_metadata(trajectories, 2), {"train": trajectories})
    if numpy_version == "1.x":
        members = {t.key: object_array(t.position, t.particle_type, t.material_property[:, 0]) for t in trajectories}
        write_npz_as_numpy1(source / "train.npz", members)

    assert main(["convert", str(source), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "safe")]) == 0

    back = safe_copy_of(tmp_path / "safe", registry)["train"]
    for original, read in zip(trajectories, back, strict=True):
        np.testing.assert_array_equal(original.position, read.position)
        np.testing.assert_array_equal(original.particle_type, read.particle_type)
        np.testing.assert_array_equal(original.material_property, read.material_property)


@pytest.mark.parametrize("protocol", [3, 4])
def test_array_unpickler_rebuilds_arrays_dtypes_and_scalars(protocol, tmp_path):
    record = np.array([(1.5, 2)], dtype=[("x", "<f4"), ("n", ">i8")])
    matrix = np.arange(6, dtype=np.float32).reshape(2, 3)
    item = object_array(matrix, np.arange(3), np.float32(0.5), record, [1, (2, 3)])
    with zipfile.ZipFile(tmp_path / "a.npz", "w") as archive:
        archive.writestr("m.npy", numpy1_npy(item) if protocol == 3 else _npy(item))
    with zipfile.ZipFile(tmp_path / "a.npz") as archive:
        read = read_npy_object_array(archive, "m.npy")
    assert read.shape == (5,) and read.dtype == object
    np.testing.assert_array_equal(read[0], item[0])
    assert read[0].dtype == np.float32 and read[1].dtype == item[1].dtype
    assert read[2] == np.float32(0.5) and type(read[2]) is np.float32
    assert read[3].dtype == record.dtype and read[3].tolist() == record.tolist()
    assert read[4] == [1, (2, 3)]


def _npy(item: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, item)
    return buffer.getvalue()


def test_array_unpickler_refuses_numpy_globals_beyond_arrays(tmp_path):
    """A masked array needs ``numpy.ma``: more than arrays, so refused before anything is called."""
    with zipfile.ZipFile(tmp_path / "a.npz", "w") as archive:
        archive.writestr("m.npy", _npy(object_array(np.ma.masked_array([1.0, 2.0]), np.arange(2))))
    with zipfile.ZipFile(tmp_path / "a.npz") as archive, pytest.raises(RefusedGlobal) as info:
        read_npy_object_array(archive, "m.npy")
    assert info.value.global_name == "numpy.ma.core._mareconstruct"


def test_damaged_pickle_is_named_by_file_and_member(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "npz")
    cls.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories})
    whole = numpy1_npy(object_array(trajectories[0].position, trajectories[0].particle_type))
    with zipfile.ZipFile(tmp_path / "train.npz", "w") as archive:
        archive.writestr("simulation_trajectory_0.npy", whole[: len(whole) // 2])
    with pytest.raises(DatasetError, match=r"train\.npz: simulation_trajectory_0: not a numpy object array of arrays "
                                           r"\(truncated or corrupt\?\): "):
        cls(cls.Params(), tmp_path).split("train")[0]


# --- every command that reads data refuses a hostile file ----------------------------------------------------


@pytest.fixture(scope="module")
def trained_state(dataset_2d, tmp_path_factory):
    """The state of a tiny model trained one step on ``dataset_2d``, to store under recipes of our choosing."""
    trainer = tiny_trainer(tiny_recipe(dataset_2d), tmp_path_factory.mktemp("granting") / "run")
    trainer.train(1)
    trainer.close()
    return trainer.state()


def granting_checkpoint(state: dict, path: Path, dataset: Path) -> Path:
    """A checkpoint as earlier versions wrote it for a recipe with ``dataset: {name: npz, allow_pickle: true}``."""
    recipe = {**state["recipe"], "dataset": {"name": "npz", "path": str(dataset), "allow_pickle": True}}
    return save_checkpoint(path, {**state, "recipe": recipe})


def _convert(hostile, trusted, tmp_path, state):
    return ["convert", str(hostile), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "out")]


def _train(hostile, trusted, tmp_path, state):
    recipe = tiny_recipe_mapping(hostile, tmp_path / "run")
    recipe["dataset"]["name"] = "npz"
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    return ["train", str(tmp_path / "recipe.yaml"), "--no-progress", "--no-tracking"]


def _rollout_of_its_own_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", hostile)
    return ["rollout", str(checkpoint), "--no-progress"]


def _rollout_of_other_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", trusted)
    return ["rollout", str(checkpoint), "--dataset", str(hostile), "--no-progress"]


def _evaluate_of_its_own_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", hostile)
    return ["evaluate", str(checkpoint), "--no-simulator", "--out", str(tmp_path / "report")]


def _evaluate_of_other_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", trusted)
    return ["evaluate", str(checkpoint), "--dataset", str(hostile), "--no-simulator", "--out", str(tmp_path / "report")]


COMMANDS = [_convert, _train, _rollout_of_its_own_data, _rollout_of_other_data, _evaluate_of_its_own_data,
            _evaluate_of_other_data]


@pytest.mark.parametrize("command", COMMANDS, ids=[c.__name__.lstrip("_") for c in COMMANDS])
def test_hostile_file_is_refused_by_every_command_that_reads_data(command, dataset_2d, trained_state, tmp_path, capsys):
    """Refused by name (file, member, global) with an opt-in the command takes; checkpoints' stored grants are void."""
    marker = tmp_path / "marker"
    hostile = write_hostile_dataset(tmp_path / "hostile", metadata_of(dataset_2d), marker)
    trusted = Path(shutil.copytree(dataset_2d, tmp_path / "trusted"))
    argv = command(hostile, trusted, tmp_path, trained_state)

    code = main(argv)

    err = capsys.readouterr().err
    assert not marker.exists(), "the payload ran"
    assert code == 2, err
    assert re.search(rf"{re.escape(str(hostile))}/\w+\.npz: {MEMBER}: refused to unpickle builtins\.exec", err), err
    assert f"--allow-pickle {hostile} " in err
    # The opt-in the message suggests exists for this command.
    build_parser([argv[0]]).parse_args([*argv, "--allow-pickle", str(hostile)])


def test_a_recipe_cannot_grant_unpickling(dataset_2d, tmp_path, capsys):
    marker = tmp_path / "marker"
    hostile = write_hostile_dataset(tmp_path / "hostile", metadata_of(dataset_2d), marker)
    recipe = tiny_recipe_mapping(hostile, tmp_path / "run")
    recipe["dataset"].update(name="npz", allow_pickle=True)
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))

    code = main(["train", str(tmp_path / "recipe.yaml"), "--no-progress", "--no-tracking"])

    err = capsys.readouterr().err
    assert not marker.exists(), "the payload ran"
    assert code == 2 and "dataset.allow_pickle: a recipe cannot grant unpickling" in err, err
    assert "--allow-pickle FOLDER" in err


# --- files that need more than arrays: a grant per command, for one folder -----------------------------------


def write_masked(folder: Path, source: Path, registry) -> Path:
    """``source`` in the geoelements layout with masked positions: benign, but its pickle needs ``numpy.ma``."""
    folder.mkdir()
    shutil.copy(source / "metadata.json", folder)
    for split, trajectories in safe_copy_of(source, registry).items():
        members = {t.key: object_array(np.ma.masked_array(t.position), t.particle_type) for t in trajectories}
        np.savez(folder / f"{split}.npz", **members)
    return folder


def test_allow_pickle_grants_one_folder_for_one_command(dataset_2d, tmp_path, registry, capsys):
    data = write_masked(tmp_path / "masked", dataset_2d, registry)
    convert = ["convert", str(data), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "safe")]

    assert main(convert) == 2
    err = capsys.readouterr().err
    assert "train.npz: train_000: refused to unpickle numpy.ma.core._mareconstruct" in err, err
    assert main([*convert, "--allow-pickle", str(dataset_2d)]) == 2
    err = capsys.readouterr().err
    assert f"--allow-pickle {dataset_2d}: this command reads the dataset in {data}" in err, err
    assert main([*convert, "--allow-pickle", str(data)]) == 0
    converted, original = safe_copy_of(tmp_path / "safe", registry), safe_copy_of(dataset_2d, registry)
    np.testing.assert_array_equal(converted["train"][0].position, original["train"][0].position)

    recipe = tiny_recipe_mapping(data, tmp_path / "run")
    recipe["dataset"]["name"] = "npz"
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    train = ["train", str(tmp_path / "recipe.yaml"), "--steps", "1", "--no-progress", "--no-tracking"]
    assert main([*train, "--allow-pickle", str(data)]) == 0, capsys.readouterr().err
    checkpoint = next((tmp_path / "run" / "checkpoints").glob("checkpoint-*.pt"))
    rollout = ["rollout", str(checkpoint), "--steps", "2", "--trajectories", "1", "--no-progress"]
    # The checkpoint of a granted run holds no grant: the next command needs its own.
    assert main(rollout) == 2 and "refused to unpickle numpy.ma.core._mareconstruct" in capsys.readouterr().err
    assert main([*rollout, "--allow-pickle", str(data)]) == 0, capsys.readouterr().err
