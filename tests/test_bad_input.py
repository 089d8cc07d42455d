"""Bad input: a clear error naming the file and the field, and nothing already written is touched."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from tiny import tiny_recipe, tiny_trainer

from gns_framework.cli import main
from gns_framework.errors import CheckpointError
from gns_framework.io.checkpoint import FORMAT, load_checkpoint

pytestmark = [pytest.mark.stability, pytest.mark.usefixtures("one_torch_thread")]

GNS = Path(sys.executable).parent / "gns"


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def write_recipe(path: Path, dataset: Path, **model) -> Path:
    raw = tiny_recipe(dataset, **model).model_dump(mode="json")
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture(scope="module")
def trained(dataset_2d, tmp_path_factory):
    """A run folder with one checkpoint and its metrics, and the recipe that made it."""
    root = tmp_path_factory.mktemp("bad-input")
    trainer = tiny_trainer(tiny_recipe(dataset_2d), root / "run")
    trainer.train(1)
    trainer.close()
    return root / "run", write_recipe(root / "recipe.yaml", dataset_2d)


@pytest.fixture
def run_dir(trained, tmp_path):
    """A fresh copy of the trained run, so a test that fails cannot damage the others."""
    return Path(shutil.copytree(trained[0], tmp_path / "run"))


def _members(file: Path) -> dict[str, np.ndarray]:
    with np.load(file, allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def _rewrite(file: Path, change) -> None:
    members = _members(file)
    change(members)
    np.savez(file, **members)


def flat_position(data: Path) -> None:
    _rewrite(data / "train.npz", lambda m: m.update({"train_000/position": m["train_000/position"][:, :, 0]}))


def nan_position(data: Path) -> None:
    def change(m):
        m["train_001/position"] = m["train_001/position"].copy()
        m["train_001/position"][4, 7, 1] = np.nan

    _rewrite(data / "train.npz", change)


def short_particle_type(data: Path) -> None:
    _rewrite(data / "train.npz", lambda m: m.update({"train_000/particle_type": m["train_000/particle_type"][:-1]}))


def pickled_member(data: Path) -> None:
    members = _members(data / "train.npz")
    members["train_000/position"] = np.array([members["train_000/position"]], dtype=object)
    np.savez(data / "train.npz", **members)


def three_dimensional_metadata(data: Path) -> None:
    raw = json.loads((data / "metadata.json").read_text())
    raw.update(
        dim=3, bounds=raw["bounds"] + [[0, 1]], vel_mean=[0] * 3, vel_std=[1] * 3, acc_mean=[0] * 3, acc_std=[1] * 3
    )
    (data / "metadata.json").write_text(json.dumps(raw))


def negative_std(data: Path) -> None:
    raw = json.loads((data / "metadata.json").read_text())
    raw["vel_std"] = [-1.0, 1.0]
    (data / "metadata.json").write_text(json.dumps(raw))


def truncate(name: str):
    def damage(data: Path) -> None:
        content = (data / name).read_bytes()
        (data / name).write_bytes(content[: len(content) // 2])

    damage.__name__ = f"truncated {name}"
    return damage


DAMAGED_DATA = [
    (flat_position, r"train\.npz: trajectory 'train_000': position: expected shape \(T, N, d\)"),
    (nan_position, r"train\.npz: trajectory 'train_001': position: non-finite value at frame 4, particle 7"),
    (short_particle_type, r"train\.npz: trajectory 'train_000': particle_type: expected shape"),
    (
        pickled_member,
        r"train\.npz: train_000/position: holds a pickled object array, but this layout stores plain "
        r"numeric arrays only and never unpickles$",
    ),
    (three_dimensional_metadata, r"train\.npz: trajectory 'train_000': position: has d = 2 but metadata says dim = 3"),
    (negative_std, r"metadata\.json: invalid metadata: .*vel_std must be finite and >= 0"),
    (truncate("train.npz"), r"train\.npz: not a readable \.npz archive \(truncated or corrupt\?\)"),
    (truncate("metadata.json"), r"metadata\.json: not valid JSON"),
]


@pytest.mark.parametrize("damage, expected", DAMAGED_DATA, ids=[d.__name__ for d, _ in DAMAGED_DATA])
def test_damaged_dataset_is_named_and_the_run_is_untouched(
    damage, expected, dataset_2d, trained, run_dir, tmp_path, capsys
):
    data = Path(shutil.copytree(dataset_2d, tmp_path / "data"))
    damage(data)
    before, data_before = snapshot(run_dir), snapshot(data)
    code = main(["train", str(trained[1]), "--dataset", str(data), "--out", str(run_dir), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("gns train: error: ")
    assert re.search(expected, err), err
    assert snapshot(run_dir) == before and snapshot(data) == data_before


MALFORMED_RECIPES = [
    ("name: x\ndataset: {path: d\n", r"recipe\.yaml: 1 problem.*line 3.*invalid YAML"),
    (
        "name: x\ndataset: {path: d}\nmodel: {latent_size: 0}\nrollout: {guard: {on_violation: later}}\n",
        r"recipe\.yaml: 2 problem.*model\.latent_size.*rollout\.guard\.on_violation",
    ),
    ("- just\n- a list\n", r"recipe\.yaml: 1 problem.*expected a mapping"),
]


@pytest.mark.parametrize("text, expected", MALFORMED_RECIPES, ids=["yaml syntax", "bad fields", "not a mapping"])
def test_malformed_recipe_is_named_and_the_run_is_untouched(text, expected, run_dir, tmp_path, capsys):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(text)
    before = snapshot(run_dir)
    assert main(["train", str(recipe), "--out", str(run_dir), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert re.search(expected, err, flags=re.DOTALL), err
    assert snapshot(run_dir) == before


def test_resuming_with_another_recipe_is_refused_and_the_checkpoint_kept(dataset_2d, run_dir, tmp_path, capsys):
    other = write_recipe(tmp_path / "other.yaml", dataset_2d, latent_size=32)
    before = snapshot(run_dir)
    assert main(["train", str(other), "--out", str(run_dir), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "checkpoint-000000001.pt: written for a different model: model.latent_size: checkpoint 16, recipe 32" in err
    assert snapshot(run_dir) == before


def test_truncated_checkpoint_is_named_and_earlier_rollouts_are_kept(run_dir, tmp_path, capsys):
    checkpoint = run_dir / "checkpoints" / "checkpoint-000000001.pt"
    damaged = tmp_path / "damaged.pt"
    damaged.write_bytes(checkpoint.read_bytes()[:1000])
    out = tmp_path / "rollouts"
    out.mkdir()
    (out / "test_0000.npz").write_bytes(b"earlier")
    assert main(["rollout", str(damaged), "--out", str(out), "--no-progress"]) == 2
    assert "damaged.pt: unreadable checkpoint (truncated, corrupt or not a checkpoint)" in capsys.readouterr().err
    assert snapshot(out) == {"test_0000.npz": b"earlier"}


class _Payload:
    """Unpickling this would create ``marker``: proof that code from the file ran."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_checkpoint_with_pickled_code_is_refused_without_running_it(tmp_path):
    marker = tmp_path / "code-ran"
    path = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "model": {}, "payload": _Payload(marker)}, path)
    with pytest.raises(CheckpointError, match=r"evil\.pt: unreadable checkpoint"):
        load_checkpoint(path)
    assert not marker.exists()


def test_rollout_of_a_checkpoint_on_data_of_another_dimension_is_refused(run_dir, tmp_path, capsys):
    from synthetic import write_synthetic_dataset

    data3d = write_synthetic_dataset(tmp_path / "d3", train=1, valid=0, test=1, dim=3, frames=8)
    out = tmp_path / "rollouts"
    code = main(
        [
            "rollout",
            str(run_dir / "checkpoints" / "checkpoint-000000001.pt"),
            "--dataset",
            str(data3d),
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert code == 2
    assert "d3/metadata.json: dim: the dataset has dim = 3 but the model simulates dim = 2" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["train", "recipe.yaml", "--steps", "-5"], "argument --steps: must be >= 1, got -5"),
        (["rollout", "x.pt", "--trajectories", "0"], "argument --trajectories: must be >= 1, got 0"),
        (["rollout", "x.pt", "--guard-margin", "nan"], "argument --guard-margin: must be a finite number >= 0"),
        (["rollout", "x.pt", "--on-violation", "ignore"], "argument --on-violation: invalid choice: 'ignore'"),
    ],
)
def test_bad_command_line_arguments_exit_with_code_2(argv, expected, tmp_path):
    done = subprocess.run([str(GNS), *argv], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 2
    assert expected in done.stderr
    assert list(tmp_path.iterdir()) == []
