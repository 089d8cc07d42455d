"""``gns train`` (``gns_framework.cli.train``): bad arguments exit 2 with a message, and a ``--resume`` with
nothing to resume starts at step 0 and says so. Resuming, fine-tuning, restarts and tracking are tested with the
trainer (tests/training/), and end to end with the rollout that follows (test_cli_rollout.py)."""

from __future__ import annotations

import yaml
from cli_runner import gns
from tiny import tiny_recipe_mapping

from gns_framework.cli import main


def test_bad_arguments_exit_2_with_a_message(tmp_path):
    result = gns("train", "recipes/water2d.yaml", "--steps", "many")
    assert result.returncode == 2 and "invalid int value" in result.stderr
    missing = gns("train", str(tmp_path / "nope.yaml"))
    assert missing.returncode == 2 and "nope.yaml" in missing.stderr and "file not found" in missing.stderr


def test_resume_without_a_checkpoint_starts_at_step_0_and_reports_the_run(dataset_2d, tmp_path, capsys):
    recipe = tmp_path / "tiny.yaml"
    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"]["device"] = "cuda:0"  # --device overrides it: this runs on any machine
    recipe.write_text(yaml.safe_dump(raw))
    run = tmp_path / "run"
    argv = ["train", str(recipe), "--out", str(run), "--steps", "1", "--device", "cpu", "--resume"]
    assert main([*argv, "--no-tracking", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "no checkpoint to resume from; starting at step 0" in out
    # --steps 1 overrides the recipe's 3 steps; the last line names the run, its step and its checkpoints.
    assert "trained tiny to step 1, valid_one_step_loss " in out and f"; checkpoints in {run / 'checkpoints'}" in out
    assert sorted(p.name for p in (run / "checkpoints").glob("*.pt")) == ["checkpoint-000000001.pt"]


def test_the_last_step_is_validated_once_and_a_run_resumed_at_its_end_validates(
    dataset_2d, tmp_path, monkeypatch, capsys
):
    from gns_framework.training.trainer import Trainer

    calls = []
    validate = Trainer.validate

    def counted(self):
        calls.append(self.step)
        return validate(self)

    monkeypatch.setattr(Trainer, "validate", counted)
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(dataset_2d)))
    argv = ["train", str(recipe), "--out", str(tmp_path / "run"), "--steps", "2", "--no-tracking", "--no-progress"]
    assert main(argv) == 0
    assert calls == [2], "the loop's validation at its last step is the summary's: no second one"
    assert main([*argv, "--resume"]) == 0
    assert calls == [2, 2], "nothing left to train: the summary validates"
    assert "trained tiny to step 2, valid_one_step_loss " in capsys.readouterr().out


def test_sigterm_marks_the_mlflow_run_killed_releases_the_lock_and_keeps_the_checkpoints(dataset_2d, tmp_path):
    """A scheduler's stop (SIGTERM) ends training as Ctrl-C does: exit 143 with one line naming the checkpoint to
    resume from, the MLflow run KILLED (not left RUNNING), the lock gone, every checkpoint kept (issue 47)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import mlflow

    from gns_framework.io.checkpoint import list_checkpoints
    from gns_framework.io.run_folder import RunFolder

    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"].update(steps=100_000, checkpoint_every=2, validate_every=100_000, log_every=1)
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(raw))
    run, store = tmp_path / "run", f"sqlite:///{tmp_path / 'mlflow.db'}"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MLFLOW_TRACKING_URI": store}
    command = [sys.executable, "-m", "gns_framework.cli", "train", str(recipe), "--out", str(run), "--no-progress"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 300
        while not list_checkpoints(run / "checkpoints") and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.2)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 128 + signal.SIGTERM, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("gns train: stopped by SIGTERM at step ") and "the newest checkpoint is" in last, err
    assert not RunFolder(run).lock.exists()
    assert list_checkpoints(run / "checkpoints")
    run_id = __import__("json").loads(RunFolder(run).mlflow_run.read_text())["run_id"]
    assert mlflow.MlflowClient(store).get_run(run_id).info.status == "KILLED"


def test_a_time_limit_stops_with_a_checkpoint_that_resumes_to_the_end(dataset_2d, tmp_path, monkeypatch, capsys):
    from gns_framework.training import progress

    clock = iter(range(0, 10_000, 50))  # every look at the deadline's clock: 50 s later
    monkeypatch.setattr(progress.Deadline, "clock", staticmethod(lambda: float(next(clock))))
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(dataset_2d)))
    run = tmp_path / "run"
    argv = ["train", str(recipe), "--out", str(run), "--steps", "6", "--no-tracking", "--no-progress"]
    assert main([*argv, "--time-limit", "2.5"]) == 0  # 150 s: the deadline started at 0, steps end at 50, 100, 150
    out = capsys.readouterr().out
    assert "stopped at the time limit (2.5 min) at step 3 of 6" in out and "go on with --resume" in out
    assert sorted(p.name for p in (run / "checkpoints").glob("checkpoint-*.pt")) == ["checkpoint-000000003.pt"]
    monkeypatch.undo()
    assert main([*argv, "--resume"]) == 0
    assert "resumed from" in (out := capsys.readouterr().out) and "trained tiny to step 6" in out
