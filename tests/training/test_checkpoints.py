"""Checkpoints: exact resume, surviving kill -9, damage detected and named, no checkpoint of a history lost."""

from __future__ import annotations

import shutil
import signal
import struct
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from training_support import gns_command, last_logged_step, subprocess_env, tiny_recipe, wait_until, write_recipe

from gns_framework.cli import main
from gns_framework.config.recipe import validate_recipe
from gns_framework.errors import CheckpointError
from gns_framework.io.checkpoint import FORMAT, list_checkpoints, load_checkpoint
from gns_framework.io.run_folder import checkpoint_name
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer


def make_trainer(recipe: dict, run_dir) -> Trainer:
    registry = load_registry()
    return Trainer(validate_recipe(recipe, registry), registry, run_dir=run_dir, progress=False)


def test_training_2n_steps_equals_n_then_resumed_n(uneven_dataset, tmp_path):
    n = 4
    recipe = tiny_recipe(uneven_dataset, steps=2 * n, checkpoint_every=100)
    straight = make_trainer(recipe, tmp_path / "straight")
    straight_losses = straight.train(2 * n)
    straight.close()

    first = make_trainer(recipe, tmp_path / "stopped")
    first_losses = first.train(n)
    first.close()
    resumed = make_trainer(recipe, tmp_path / "stopped")
    assert resumed.checkpoints.resume() == tmp_path / "stopped" / "checkpoints" / checkpoint_name(n)
    assert resumed.step == n
    resumed_losses = resumed.train(2 * n)
    resumed.close()

    torch.testing.assert_close(
        torch.tensor(first_losses + resumed_losses), torch.tensor(straight_losses), rtol=1e-6, atol=0
    )
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=1e-6, atol=1e-9, msg=name)
    straight_adam = straight.optimizer.state_dict()["state"]
    for key, state in resumed.optimizer.state_dict()["state"].items():
        torch.testing.assert_close(state["exp_avg_sq"], straight_adam[key]["exp_avg_sq"], rtol=1e-6, atol=1e-12)


@pytest.fixture
def two_checkpoints(uneven_dataset, tmp_path):
    """A run folder with checkpoints at steps 2 and 4, and its recipe."""
    recipe = tiny_recipe(uneven_dataset, steps=4, checkpoint_every=2)
    trainer = make_trainer(recipe, tmp_path / "run")
    trainer.train()
    trainer.close()
    return tmp_path / "run", recipe


DAMAGE = {
    "truncated": lambda data: data[: len(data) // 2],
    "random bytes": lambda data: np.random.default_rng(0).bytes(len(data)),
    # A pickle that refers to an object it never stored: the unpickler raises KeyError.
    "dangling pickle reference": lambda data: b"\x80\x02h\x05.",
}


def flip_tensor_byte(path: Path) -> None:
    """Flip one exponent bit of a float in the largest tensor record of the checkpoint archive at ``path``."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as archive:
        record = max((i for i in archive.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    name_length, extra_length = struct.unpack_from("<HH", data, record.header_offset + 26)
    start = record.header_offset + 30 + name_length + extra_length
    data[start + (record.file_size // 8) * 4 + 3] ^= 0x40  # the high byte of a little-endian float32
    path.write_bytes(bytes(data))


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def train_cli(recipe: dict, run_dir: Path, *extra: str) -> int:
    recipe_file = write_recipe(run_dir.parent / f"{run_dir.name}.yaml", recipe)
    return main(["train", str(recipe_file), "--out", str(run_dir), "--no-tracking", "--no-progress", *extra])


def test_a_flipped_byte_in_tensor_data_is_refused_naming_the_file(two_checkpoints):
    run_dir, _ = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    flip_tensor_byte(newest)
    with pytest.raises(CheckpointError, match=f"{newest}: damaged checkpoint, its bytes changed after it was written"):
        load_checkpoint(newest)


def test_a_record_rewritten_with_a_matching_crc_is_refused_by_the_digest(two_checkpoints, tmp_path):
    """The SHA-256 written with a checkpoint catches what a CRC-32 may not: here a record whose CRC was redone."""
    run_dir, _ = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    rewritten = tmp_path / "rewritten.pt"
    with zipfile.ZipFile(newest) as original, zipfile.ZipFile(rewritten, "w") as copy:
        records = original.infolist()
        changed = max((i for i in records if "/data/" in i.filename), key=lambda i: i.file_size)
        for info in records:
            data = original.read(info)
            copy.writestr(info, data[:-1] + bytes([data[-1] ^ 1]) if info is changed else data)
    with pytest.raises(CheckpointError, match=r"rewritten\.pt: damaged checkpoint.*SHA-256 [0-9a-f]{64} differs"):
        load_checkpoint(rewritten)


def test_a_checkpoint_written_before_the_digest_loads_and_its_crcs_are_checked(two_checkpoints, tmp_path):
    run_dir, _ = two_checkpoints
    state = load_checkpoint(run_dir / "checkpoints" / checkpoint_name(4))
    older = tmp_path / checkpoint_name(4)
    torch.save(state, older)  # as save_checkpoint wrote them before: no digest record
    assert load_checkpoint(older)["step"] == 4 and load_checkpoint(older)["format"] == FORMAT
    flip_tensor_byte(older)
    with pytest.raises(
        CheckpointError, match=f"{older}: damaged checkpoint.*: record data/[0-9]+ does not match its CRC-32"
    ):
        load_checkpoint(older)


@pytest.mark.parametrize("damage", DAMAGE)
def test_damaged_checkpoint_error_names_the_file_and_resume_falls_back(two_checkpoints, damage):
    run_dir, recipe = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    newest.write_bytes(DAMAGE[damage](newest.read_bytes()))

    with pytest.raises(CheckpointError, match=f"{newest}: unreadable checkpoint"):
        load_checkpoint(newest)
    trainer = make_trainer(recipe, run_dir)
    with pytest.warns(UserWarning, match=f"skipping damaged checkpoint: {newest}"):
        resumed_from = trainer.checkpoints.resume()
    trainer.close()
    assert resumed_from == run_dir / "checkpoints" / checkpoint_name(2) and trainer.step == 2


def test_resume_past_a_damaged_checkpoint_keeps_it_aside_and_never_writes_over_it(two_checkpoints):
    run_dir, recipe = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    flip_tensor_byte(newest)
    damaged = newest.read_bytes()
    trainer = make_trainer(recipe, run_dir)
    with pytest.warns(UserWarning, match=f"damaged checkpoint {newest} kept as {newest.name}.damaged"):
        assert trainer.checkpoints.resume() == run_dir / "checkpoints" / checkpoint_name(2)
    trainer.train(4)
    trainer.close()
    assert (run_dir / "checkpoints" / f"{newest.name}.damaged").read_bytes() == damaged
    assert load_checkpoint(newest)["step"] == 4


def test_auto_resume_with_every_checkpoint_damaged_stops_naming_them_and_touches_nothing(two_checkpoints, capsys):
    run_dir, recipe = two_checkpoints
    checkpoints = [run_dir / "checkpoints" / checkpoint_name(step) for step in (2, 4)]
    for path in checkpoints:
        flip_tensor_byte(path)
    before = snapshot(run_dir / "checkpoints")
    assert train_cli(recipe, run_dir, "--resume") == 2
    err = capsys.readouterr().err
    assert "every checkpoint is damaged, nothing to resume from (all are left as they are)" in err
    assert all(f"{path}: damaged checkpoint" in err for path in checkpoints), err
    assert "--restart" in err
    assert snapshot(run_dir / "checkpoints") == before


def test_restart_starts_afresh_and_moves_the_earlier_checkpoints_aside_whole(two_checkpoints, capsys):
    run_dir, recipe = two_checkpoints
    for step in (2, 4):
        flip_tensor_byte(run_dir / "checkpoints" / checkpoint_name(step))
    before = snapshot(run_dir / "checkpoints")
    assert train_cli(recipe, run_dir, "--restart", "--steps", "2") == 0
    assert f"starting afresh at step 0; the earlier run's checkpoints are kept in {run_dir / 'earlier-1'}" in (
        capsys.readouterr().out
    )
    assert snapshot(run_dir / "earlier-1" / "checkpoints") == before
    assert [step for step, _ in list_checkpoints(run_dir / "checkpoints")] == [2]


def test_starting_at_step_0_in_a_folder_holding_checkpoints_is_refused(two_checkpoints, capsys):
    run_dir, recipe = two_checkpoints
    before = snapshot(run_dir / "checkpoints")
    assert train_cli(recipe, run_dir) == 2
    err = capsys.readouterr().err
    assert (
        f"{run_dir / 'checkpoints'}: holds checkpoints of an earlier run ({checkpoint_name(2)}, {checkpoint_name(4)})"
        in err
    )
    assert "--resume" in err and "--restart" in err
    assert snapshot(run_dir / "checkpoints") == before


def test_resuming_before_newer_checkpoints_is_refused_and_a_branch_goes_to_its_own_folder(two_checkpoints, capsys):
    """Resumed at step 2 beside step 4, training would overwrite 4, and with fewer kept, prune its own new ones."""
    run_dir, recipe = two_checkpoints
    older = run_dir / "checkpoints" / checkpoint_name(2)
    before = snapshot(run_dir / "checkpoints")
    assert train_cli(recipe, run_dir, "--resume", str(older)) == 2
    err = capsys.readouterr().err
    assert f"{older}: resuming at step 2 would overwrite and prune the newer checkpoints" in err
    assert f"({checkpoint_name(4)})" in err and f"--out DIR --resume {older}" in err
    assert snapshot(run_dir / "checkpoints") == before

    branch = run_dir.parent / "branch"
    assert (
        train_cli(dict(recipe, training=dict(recipe["training"], keep_checkpoints=1)), branch, "--resume", str(older))
        == 0
    )
    assert [step for step, _ in list_checkpoints(branch / "checkpoints")] == [4]
    assert snapshot(run_dir / "checkpoints") == before


def test_resuming_into_a_folder_holding_another_runs_checkpoints_is_refused(two_checkpoints, tmp_path, capsys):
    run_dir, recipe = two_checkpoints
    other = tmp_path / "other"
    shutil.copytree(run_dir / "checkpoints", other / "checkpoints")
    before = snapshot(other / "checkpoints")
    elsewhere = run_dir / "checkpoints" / checkpoint_name(2)
    assert train_cli(recipe, other, "--resume", str(elsewhere)) == 2
    assert (
        f"{elsewhere}: resuming from outside {other / 'checkpoints'}, which holds checkpoints"
        in capsys.readouterr().err
    )
    assert snapshot(other / "checkpoints") == before


def test_resume_from_a_directory_says_so_and_lists_its_checkpoints(two_checkpoints, capsys):
    run_dir, recipe = two_checkpoints
    names = f"{checkpoint_name(2)}, {checkpoint_name(4)}"
    assert train_cli(recipe, run_dir, "--resume", str(run_dir / "checkpoints")) == 2
    assert f"{run_dir / 'checkpoints'}: a directory, not a checkpoint file; it holds {names}" in capsys.readouterr().err
    assert train_cli(recipe, run_dir, "--resume", str(run_dir)) == 2
    assert f"{run_dir}: a directory, not a checkpoint file; a run folder, whose checkpoints/ holds {names}" in (
        capsys.readouterr().err
    )
    empty = run_dir.parent / "empty"
    empty.mkdir()
    assert train_cli(recipe, run_dir, "--resume", str(empty)) == 2
    assert f"{empty}: a directory, not a checkpoint file; it holds no checkpoints (*.pt)" in capsys.readouterr().err


def test_resume_from_a_named_damaged_checkpoint_is_refused_naming_it(two_checkpoints, tmp_path, capsys):
    run_dir, recipe = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    newest.write_bytes(newest.read_bytes()[:1000])
    recipe_file = write_recipe(tmp_path / "recipe.yaml", recipe)
    code = main(
        ["train", str(recipe_file), "--out", str(run_dir), "--resume", str(newest), "--no-tracking", "--no-progress"]
    )
    assert code == 2
    assert f"{newest}: unreadable checkpoint" in capsys.readouterr().err


def test_partial_checkpoint_writes_are_cleared_by_the_next_save(two_checkpoints):
    run_dir, recipe = two_checkpoints
    partial = run_dir / "checkpoints" / ".checkpoint-000000006.pt.abc123.tmp.pt"
    partial.write_bytes(b"half a checkpoint")
    trainer = make_trainer(recipe, run_dir)
    trainer.checkpoints.resume()
    trainer.train(6)
    trainer.close()
    assert not partial.exists()
    assert [step for step, _ in list_checkpoints(run_dir / "checkpoints")] == [2, 4, 6]


def test_kill_9_loses_at_most_one_checkpoint_interval_and_resume_completes(uneven_dataset, tmp_path):
    every = 4
    recipe_file = write_recipe(
        tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=100_000, checkpoint_every=every)
    )
    run_dir, env = tmp_path / "run", subprocess_env()
    command = gns_command("train", str(recipe_file), "--out", str(run_dir), "--no-tracking", "--no-progress")
    job = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        wait_until(
            lambda: [s for s, _ in list_checkpoints(run_dir / "checkpoints") if s >= 2 * every],
            120,
            "a checkpoint",
            job,
        )
    finally:
        job.send_signal(signal.SIGKILL)
        job.communicate(timeout=60)
    reached = last_logged_step(run_dir)
    newest = list_checkpoints(run_dir / "checkpoints")[-1][0]
    assert reached - newest <= every, f"killed at step >= {reached} but the newest checkpoint is of step {newest}"

    finish = newest + every
    resumed = subprocess.run(
        [*command, "--resume", "--steps", str(finish)],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"{checkpoint_name(newest)} at step {newest}" in resumed.stdout
    assert load_checkpoint(run_dir / "checkpoints" / checkpoint_name(finish))["step"] == finish
    assert not list((run_dir / "checkpoints").glob(".checkpoint-*")), "partial writes left behind"
