"""One writer per run folder (issue 30, item 3): a second ``gns train`` is refused naming the holder, a lock whose
process is gone is taken over, and retention prunes only the run's own history and never a damaged checkpoint,
so the advice the refusals give can be followed without losing a checkpoint."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys

import pytest
from test_checkpoints import flip_tensor_byte, snapshot, train_cli
from training_support import subprocess_env, tiny_recipe

from gns_framework.io.checkpoint import list_checkpoints
from gns_framework.io.run_folder import RunFolder, checkpoint_name
from gns_framework.training.run_lock import RunFolderLock

HOLD = """
import sys, time
from gns_framework.training.run_lock import RunFolderLock
lock = RunFolderLock(sys.argv[1]).acquire()
print("held", flush=True)
time.sleep(120)
"""


@pytest.fixture
def holder(tmp_path):
    """A process holding the lock of ``tmp_path / 'run'``."""
    run_dir = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(run_dir)], stdout=subprocess.PIPE, text=True, env=subprocess_env()
    )
    try:
        assert process.stdout.readline().strip() == "held"
        yield run_dir, process
    finally:
        process.kill()
        process.wait()


def test_a_second_writer_is_refused_in_one_line_naming_the_holder(holder, uneven_dataset, capsys):
    run_dir, process = holder
    before = snapshot(run_dir)
    assert train_cli(tiny_recipe(uneven_dataset, steps=2), run_dir) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"gns train: error: {run_dir}: another gns train is writing into this run folder" in err
    assert f"pid {process.pid} on host {socket.gethostname()}, since 20" in err
    assert snapshot(run_dir) == before  # nothing written: no checkpoint, no metrics, no recipe.yaml


@pytest.mark.parametrize("flag", [[], ["--resume"], ["--restart"]])
def test_resume_and_restart_are_refused_too(holder, uneven_dataset, capsys, flag):
    run_dir, _ = holder
    assert train_cli(tiny_recipe(uneven_dataset, steps=2), run_dir, *flag) == 2
    assert "another gns train is writing into this run folder" in capsys.readouterr().err


def test_the_lock_is_held_for_the_whole_run_and_removed_after(uneven_dataset, tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    seen = []
    from gns_framework.training import trainer as trainer_module

    original = trainer_module.Trainer.train

    def train(self, *args, **kwargs):
        with pytest.raises(Exception, match="another gns train is writing"):
            RunFolderLock(run_dir).acquire()
        seen.append(json.loads((run_dir / RunFolder.LOCK).read_text()))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(trainer_module.Trainer, "train", train)
    assert train_cli(tiny_recipe(uneven_dataset, steps=2), run_dir) == 0
    import os

    assert seen and seen[0]["pid"] == os.getpid() and seen[0]["host"] == socket.gethostname()
    assert not (run_dir / RunFolder.LOCK).exists()


def test_a_lock_left_by_a_process_that_is_gone_is_taken_over(uneven_dataset, tmp_path, capsys):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    (run_dir / RunFolder.LOCK).write_text(json.dumps({"pid": gone.pid, "host": socket.gethostname(), "since": "x"}))
    assert train_cli(tiny_recipe(uneven_dataset, steps=2), run_dir) == 0
    assert f"taking over the lock of a writer that is gone (pid {gone.pid}" in capsys.readouterr().err
    assert [s for s, _ in list_checkpoints(run_dir / "checkpoints")] == [2]


def test_a_run_that_cannot_start_leaves_no_folder(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert train_cli(tiny_recipe(tmp_path / "no-such-data", steps=2), run_dir) == 2
    assert not run_dir.exists()


def test_following_the_copy_advice_loses_no_checkpoint_of_the_folders_history(uneven_dataset, tmp_path, capsys):
    """The attack: 'copy checkpoint-N into it' and resume, and retention pruned the folder's own earlier history."""
    here, other = tmp_path / "here", tmp_path / "other"
    assert train_cli(tiny_recipe(uneven_dataset, steps=4, checkpoint_every=2, keep_checkpoints=2), here) == 0
    recipe_b = dict(tiny_recipe(uneven_dataset, steps=6, checkpoint_every=2, keep_checkpoints=3), seed=11)
    assert train_cli(recipe_b, other) == 0
    kept = snapshot(here / "checkpoints")
    source = other / "checkpoints" / checkpoint_name(6)
    continued = dict(recipe_b, training=dict(recipe_b["training"], steps=10, keep_checkpoints=2))
    assert train_cli(continued, here, "--resume", str(source)) == 2
    err = capsys.readouterr().err
    assert f"copy {source.name} into it" in err
    shutil.copy(source, here / "checkpoints")  # the advice, followed
    assert train_cli(continued, here, "--resume") == 0
    after = snapshot(here / "checkpoints")
    assert {k: after.get(k) for k in kept} == kept  # the folder's own history: every checkpoint, byte for byte
    assert [s for s, _ in list_checkpoints(here / "checkpoints")] == [2, 4, 8, 10]


def test_following_the_branch_advice_leaves_the_folder_untouched(uneven_dataset, tmp_path, capsys):
    run_dir = tmp_path / "run"
    recipe = tiny_recipe(uneven_dataset, steps=4, checkpoint_every=2)
    assert train_cli(recipe, run_dir) == 0
    before = snapshot(run_dir / "checkpoints")
    older = run_dir / "checkpoints" / checkpoint_name(2)
    assert train_cli(recipe, run_dir, "--resume", str(older)) == 2
    assert f"--out DIR --resume {older}" in capsys.readouterr().err
    assert (
        train_cli(
            dict(recipe, training=dict(recipe["training"], keep_checkpoints=1)),
            tmp_path / "DIR",
            "--resume",
            str(older),
        )
        == 0
    )
    assert snapshot(run_dir / "checkpoints") == before


def test_retention_never_deletes_a_damaged_checkpoint(uneven_dataset, tmp_path):
    run_dir = tmp_path / "run"
    recipe = tiny_recipe(uneven_dataset, steps=4, checkpoint_every=2, keep_checkpoints=3)
    assert train_cli(recipe, run_dir) == 0
    damaged = run_dir / "checkpoints" / checkpoint_name(2)
    flip_tensor_byte(damaged)
    data = damaged.read_bytes()
    with pytest.warns(UserWarning, match="retention kept a damaged checkpoint as checkpoint-000000002.pt.damaged"):
        assert (
            train_cli(dict(recipe, training=dict(recipe["training"], steps=8, keep_checkpoints=1)), run_dir, "--resume")
            == 0
        )
    assert (run_dir / "checkpoints" / (damaged.name + ".damaged")).read_bytes() == data
    assert [s for s, _ in list_checkpoints(run_dir / "checkpoints")] == [8]


# ---- links in a run folder (a folder copied from a colleague is enough) -----------------------------------------


@pytest.mark.parametrize(
    "name", [RunFolder.LOCK, RunFolder.METRICS, RunFolder.PARAMS, RunFolder.CHECKPOINTS, RunFolder.MLFLOW_RUN]
)
def test_a_run_folder_whose_files_link_elsewhere_is_refused_and_the_targets_are_untouched(
    uneven_dataset, tmp_path, capsys, name
):
    run_dir = tmp_path / "run"
    assert train_cli(tiny_recipe(uneven_dataset, steps=2), run_dir) == 0
    capsys.readouterr()
    target = tmp_path / "users_file"
    if name == RunFolder.CHECKPOINTS:
        shutil.move(run_dir / name, target)  # the checkpoints now live elsewhere, reached through the link
    else:
        target.write_text("precious\n")
        (run_dir / name).unlink(missing_ok=True)
    before = snapshot(target) if target.is_dir() else target.read_bytes()
    (run_dir / name).symlink_to(target)
    assert train_cli(tiny_recipe(uneven_dataset, steps=4), run_dir, "--resume") == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"{run_dir / name}: the run" in err and f"is a symbolic link to {target}" in err
    assert (snapshot(target) if target.is_dir() else target.read_bytes()) == before
    assert not (run_dir / RunFolder.LOCK).exists() or (run_dir / RunFolder.LOCK).is_symlink()
