"""Every error one line (issue 30, item 6): each low item of the issue, turned into an attack, gives one line on
stderr naming the file and the field, and exit status 2; the MLflow close waits, bounded, and leaves what it could not
send to `gns track-sync`; new files follow the umask."""

from __future__ import annotations

import json
import os
import stat
import warnings
from pathlib import Path

import pytest
import torch
import yaml
from synthetic import soft_sphere_trajectory, synthetic_metadata, write_synthetic_dataset
from tiny import tiny_recipe, tiny_recipe_mapping, tiny_trainer

from gns_framework.cli import main
from gns_framework.data.atomic import write_text_atomic
from gns_framework.data.metadata import load_metadata
from gns_framework.errors import DatasetError
from gns_framework.io.checkpoint import save_checkpoint
from gns_framework.io.run_folder import RunFolder
from gns_framework.plugins import load_registry
from gns_framework.training import mlflow_tracker
from gns_framework.training.mlflow_tracker import Outbox, Request


def one_line(capsys, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def train(recipe_file: Path, out: Path, *extra: str) -> int:
    return main(["train", str(recipe_file), "--out", str(out), "--no-tracking", "--no-progress", *extra])


# ---- recipes and scenes that are not UTF-8 ----------------------------------------------------------------------


def test_a_recipe_that_is_not_utf8_is_one_line(tmp_path, capsys):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_bytes(b"name: caf\xe9\n")
    assert train(recipe, tmp_path / "run") == 2
    one_line(capsys, f"gns train: error: {recipe}: byte 9: not UTF-8 text (0xe9)")


def test_a_scene_that_is_not_utf8_is_one_line(tmp_path, capsys):
    scene = tmp_path / "scene.yaml"
    scene.write_bytes(b"\xff\xfename: x\n")
    assert main(["generate", str(scene), "--trajectories", "3", "--out", str(tmp_path / "d")]) == 2
    one_line(capsys, f"gns generate: error: {scene}: byte 0: not UTF-8 text (0xff)")


# ---- metadata ---------------------------------------------------------------------------------------------------


@pytest.fixture
def dataset(tmp_path):
    return write_synthetic_dataset(tmp_path / "data", train=2, valid=1, test=1)


def edit_metadata(dataset: Path, **changes) -> Path:
    path = dataset / "metadata.json"
    metadata = json.loads(path.read_text())
    metadata.update(changes)
    path.write_text(json.dumps(metadata))  # Python writes inf as Infinity and nan as NaN, as a careless tool would
    return path


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"default_connectivity_radius": float("inf")}, "default_connectivity_radius must be finite"),
        ({"dt": float("inf")}, "dt must be finite"),
        ({"bounds": [[0.0, float("inf")], [0.0, 1.0]]}, "bounds must be finite"),
        ({"vel_mean": [float("nan"), 0.0]}, "vel_mean must be finite"),
        ({"sequence_length": 1e12}, "sequence_length: 1e+12 frames, more than the limit"),
    ],
)
def test_non_finite_or_huge_metadata_is_refused_by_field(dataset, tmp_path, capsys, changes, field):
    path = edit_metadata(dataset, **changes)
    with pytest.raises(DatasetError, match="invalid metadata"):
        load_metadata(dataset)
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(dataset)))
    assert train(recipe, tmp_path / "run") == 2
    one_line(capsys, f"gns train: error: {path}: invalid metadata:", field)


def test_metadata_linked_to_dev_zero_is_refused_without_reading_it_all(dataset, tmp_path, capsys):
    (dataset / "metadata.json").unlink()
    (dataset / "metadata.json").symlink_to("/dev/zero")
    with pytest.raises(DatasetError, match=r"metadata\.json: more than 16 MiB, too large for a metadata file"):
        load_metadata(dataset)


# ---- trajectories training cannot use ---------------------------------------------------------------------------


def write_with_train(path: Path, train: list) -> Path:
    frames = train[0].num_steps if train else 40
    valid = [soft_sphere_trajectory(9, frames=frames, key="valid_0")]
    metadata = synthetic_metadata([soft_sphere_trajectory(9, key="stats")], 2).model_copy(
        update={"sequence_length": frames}
    )
    load_registry().get("dataset", "safe").write(path, metadata, {"train": train, "valid": valid})
    return path


def test_zero_or_two_frame_trajectories_are_one_line_naming_the_dataset(tmp_path, capsys):
    two = write_with_train(tmp_path / "two", [soft_sphere_trajectory(i, frames=2, key=f"t{i}") for i in range(2)])
    recipe = tmp_path / "two.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(two)))
    assert train(recipe, tmp_path / "run2") == 2
    one_line(
        capsys,
        f"{two} (split train): sequence_length: its 2 trajectories have at most 2 frames, and training "
        "needs more than model.history",
    )
    empty = write_with_train(tmp_path / "empty", [])
    recipe = tmp_path / "empty.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(empty)))
    assert train(recipe, tmp_path / "run0") == 2
    one_line(capsys, "holds 0 trajectories")


# ---- re-signed checkpoints --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    data = write_synthetic_dataset(tmp_path_factory.mktemp("d") / "data", train=2, valid=1, test=1)
    trainer = tiny_trainer(tiny_recipe(data), tmp_path_factory.mktemp("run") / "run")
    trainer.train(1)
    path = trainer.checkpoints.save()
    trainer.close()
    return path


@pytest.mark.parametrize(
    "field, value, says",
    [
        ("step", "twelve", "step: expected a whole number >= 0, got 'twelve'"),
        ("step", -3, "step: expected a whole number >= 0, got -3"),
        ("recipe", None, "recipe: expected a mapping, got NoneType None"),
        ("scene", {"dim": 2}, "scene: not a scene record (KeyError"),
        ("rng", [1, 2], "rng: expected a mapping, got list"),
    ],
)
def test_a_re_signed_checkpoint_with_a_bad_field_is_one_line(checkpoint, tmp_path, capsys, field, value, says):
    state = torch.load(checkpoint, weights_only=True)
    state.pop("format")
    state[field] = value
    forged = save_checkpoint(tmp_path / "run" / "checkpoints" / "checkpoint-000000001.pt", state)  # digest matches
    assert main(["rollout", str(forged), "--split", "test", "--no-progress", "--out", str(tmp_path / "r")]) == 2
    one_line(capsys, f"gns rollout: error: {forged}: {says}")


def test_a_re_signed_checkpoint_without_optimizer_cannot_be_resumed(checkpoint, tmp_path, capsys):
    state = torch.load(checkpoint, weights_only=True)
    state.pop("format")
    state.pop("optimizer")
    forged = save_checkpoint(tmp_path / "elsewhere" / "checkpoint-000000001.pt", state)
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(state["recipe"]))
    assert train(recipe, tmp_path / "run", "--resume", str(forged)) == 2
    one_line(capsys, f"{forged}: optimizer: missing, so it cannot be trained on")


# ---- devices ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "device, says",
    [
        ("banana", "--device 'banana': not a device: expected auto, cpu, cuda or cuda:N"),
        ("cuda:7", "--device 'cuda:7': "),
    ],
)
def test_a_device_that_is_not_there_is_one_line(checkpoint, tmp_path, capsys, device, says):
    if device == "cuda:7" and torch.cuda.is_available() and torch.cuda.device_count() > 7:
        pytest.skip("this machine has a cuda:7")
    args = ["rollout", str(checkpoint), "--split", "test", "--no-progress", "--out", str(tmp_path / "r")]
    assert main([*args, "--device", device]) == 2
    one_line(capsys, says)


def test_train_names_training_device_for_a_bad_device(dataset, tmp_path, capsys):
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(dataset)))
    assert train(recipe, tmp_path / "run", "--device", "banana") == 2
    one_line(capsys, "training.device (or --device) 'banana': not a device")


# ---- the MLflow close at the end of training --------------------------------------------------------------------


def test_the_close_waits_for_a_server_that_comes_back(capsys):
    sent, failures = [], [5]

    def send_metrics(entries):
        if failures[0] > 0:
            failures[0] -= 1
            raise ConnectionError("connection refused")
        sent.extend(entries)

    outbox = Outbox("the server", "metrics.jsonl", send_metrics, retry_seconds=0.05, close_seconds=20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for step in range(3):
            outbox.put(Request(f"step {step}", metrics=[step], step=step))
        left = outbox.close()
    assert left == [] and sent == [0, 1, 2]  # the old close gave up at the first failure
    assert "still unreachable" in capsys.readouterr().err


def test_a_server_still_down_at_the_deadline_leaves_a_command_to_send_later(tmp_path, monkeypatch, capsys):
    pytest.importorskip("mlflow")
    monkeypatch.setenv("GNS_TRACKING_CLOSE_SECONDS", "0.5")
    monkeypatch.setenv("GNS_TRACKING_RETRY_SECONDS", "0.1")
    run_dir = tmp_path / "run"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = mlflow_tracker.open_mlflow_tracker(run_dir, uri, "exp", resume=False)
    client = tracker.client
    real_log_batch, real_terminated = client.log_batch, client.set_terminated

    def down(*args, **kwargs):
        raise ConnectionError("connection refused")

    monkeypatch.setattr(client, "log_batch", down)
    monkeypatch.setattr(client, "set_terminated", down)
    lines = [{"step": s, "time": 1.0 + s, "train_loss": 1.0 / (s + 1)} for s in range(1, 4)]
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    with (
        pytest.warns(
            UserWarning, match=rf"did not receive .* within 0.5 s; .* send them with `gns track-sync {run_dir}`"
        ),
        warnings.catch_warnings(),
    ):
        warnings.filterwarnings("ignore", message=".*unreachable.*")
        for line in lines:
            tracker.log_metrics({"train_loss": line["train_loss"]}, line["step"])
        tracker.close()
    assert json.loads((run_dir / RunFolder.MLFLOW_UNSENT).read_text())["status"] == "FINISHED"
    monkeypatch.setattr(client, "log_batch", real_log_batch)
    monkeypatch.setattr(client, "set_terminated", real_terminated)
    monkeypatch.setattr(mlflow_tracker, "_client", lambda _: client)
    assert main(["track-sync", str(run_dir), "--tracking-uri", uri]) == 0
    assert (
        f"sent 3 metric value(s) of {run_dir} to MLflow run {tracker.run_id}; marked FINISHED"
        in capsys.readouterr().out
    )
    run = client.get_run(tracker.run_id)
    assert run.info.status == "FINISHED" and not (run_dir / RunFolder.MLFLOW_UNSENT).exists()
    assert sorted(m.step for m in client.get_metric_history(tracker.run_id, "train_loss")) == [1, 2, 3]


# ---- the umask --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_new_files_follow_the_umask_and_replaced_ones_keep_their_mode(tmp_path, mask):
    old = os.umask(mask)
    try:
        write_text_atomic(tmp_path / "new.txt", "x")
        assert stat.S_IMODE((tmp_path / "new.txt").stat().st_mode) == 0o666 & ~mask  # mkstemp made it 0600
        kept = tmp_path / "kept.txt"
        kept.write_text("old")
        kept.chmod(0o640)
        write_text_atomic(kept, "new")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o640
    finally:
        os.umask(old)
