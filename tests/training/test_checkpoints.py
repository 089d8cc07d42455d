"""Checkpoints: exact resume, surviving kill -9, clear errors for damaged files and falling back past them."""

from __future__ import annotations

import signal
import subprocess

import numpy as np
import pytest
import torch
from training_support import gns_command, last_logged_step, subprocess_env, tiny_recipe, wait_until, write_recipe

from gns_framework.checkpoint import checkpoint_name, list_checkpoints, load_checkpoint
from gns_framework.cli import main
from gns_framework.errors import CheckpointError
from gns_framework.plugins import load_registry
from gns_framework.recipe import validate_recipe
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
    assert resumed.resume() == tmp_path / "stopped" / "checkpoints" / checkpoint_name(n)
    assert resumed.step == n
    resumed_losses = resumed.train(2 * n)
    resumed.close()

    torch.testing.assert_close(torch.tensor(first_losses + resumed_losses), torch.tensor(straight_losses), rtol=1e-6, atol=0)
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


@pytest.mark.parametrize("damage", DAMAGE)
def test_damaged_checkpoint_error_names_the_file_and_resume_falls_back(two_checkpoints, damage):
    run_dir, recipe = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    newest.write_bytes(DAMAGE[damage](newest.read_bytes()))

    with pytest.raises(CheckpointError, match=f"{newest}: unreadable checkpoint"):
        load_checkpoint(newest)
    trainer = make_trainer(recipe, run_dir)
    with pytest.warns(UserWarning, match=f"skipping damaged checkpoint: {newest}"):
        resumed_from = trainer.resume()
    trainer.close()
    assert resumed_from == run_dir / "checkpoints" / checkpoint_name(2) and trainer.step == 2


def test_resume_from_a_named_damaged_checkpoint_is_refused_naming_it(two_checkpoints, tmp_path, capsys):
    run_dir, recipe = two_checkpoints
    newest = run_dir / "checkpoints" / checkpoint_name(4)
    newest.write_bytes(newest.read_bytes()[:1000])
    recipe_file = write_recipe(tmp_path / "recipe.yaml", recipe)
    code = main(["train", str(recipe_file), "--out", str(run_dir), "--resume", str(newest), "--no-tracking", "--no-progress"])
    assert code == 2
    assert f"{newest}: unreadable checkpoint" in capsys.readouterr().err


def test_partial_checkpoint_writes_are_cleared_by_the_next_save(two_checkpoints):
    run_dir, recipe = two_checkpoints
    partial = run_dir / "checkpoints" / ".checkpoint-000000006.pt.abc123.tmp.pt"
    partial.write_bytes(b"half a checkpoint")
    trainer = make_trainer(recipe, run_dir)
    trainer.resume()
    trainer.train(6)
    trainer.close()
    assert not partial.exists()
    assert [step for step, _ in list_checkpoints(run_dir / "checkpoints")] == [2, 4, 6]


def test_kill_9_loses_at_most_one_checkpoint_interval_and_resume_completes(uneven_dataset, tmp_path):
    every = 4
    recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=100_000, checkpoint_every=every))
    run_dir, env = tmp_path / "run", subprocess_env()
    command = gns_command("train", str(recipe_file), "--out", str(run_dir), "--no-tracking", "--no-progress")
    job = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: [s for s, _ in list_checkpoints(run_dir / "checkpoints") if s >= 2 * every], 120, "a checkpoint", job)
    finally:
        job.send_signal(signal.SIGKILL)
        job.communicate(timeout=60)
    reached = last_logged_step(run_dir)
    newest = list_checkpoints(run_dir / "checkpoints")[-1][0]
    assert reached - newest <= every, f"killed at step >= {reached} but the newest checkpoint is of step {newest}"

    finish = newest + every
    resumed = subprocess.run(
        [*command, "--resume", "--steps", str(finish)], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"{checkpoint_name(newest)} at step {newest}" in resumed.stdout
    assert load_checkpoint(run_dir / "checkpoints" / checkpoint_name(finish))["step"] == finish
    assert not list((run_dir / "checkpoints").glob(".checkpoint-*")), "partial writes left behind"
