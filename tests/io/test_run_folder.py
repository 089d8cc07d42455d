"""The run folder's layout: the one place its paths are spelled, and what the commands find through it."""

from __future__ import annotations

from pathlib import Path

from gns_framework.io.checkpoint import list_checkpoints
from gns_framework.io.run_folder import CHECKPOINT_NAME, RunFolder, checkpoint_name


def test_every_path_of_a_run_folder(tmp_path):
    run = RunFolder(str(tmp_path / "run"))
    assert run.root == tmp_path / "run"
    assert run.checkpoint(1500) == tmp_path / "run" / "checkpoints" / "checkpoint-000001500.pt"
    assert run.best_checkpoint.relative_to(run.root) == Path("checkpoints/best.pt")
    assert run.best_record.relative_to(run.root) == Path("checkpoints/best.json")
    assert [
        p.relative_to(run.root).as_posix()
        for p in (run.recipe, run.params, run.metrics, run.mlflow_run, run.mlflow_unsent, run.lock, run.rollouts)
    ] == [
        "recipe.yaml",
        "params.json",
        "metrics.jsonl",
        "mlflow_run.json",
        "mlflow_unsent.json",
        ".gns-train.lock",
        "rollouts",
    ]
    assert RunFolder.of_checkpoint(run.checkpoint(3)) == run
    assert RunFolder.of_checkpoint(run.earlier(2) / "checkpoints" / "best.pt") == RunFolder(run.earlier(2))


def test_checkpoint_names_sort_by_step_and_are_found_again(tmp_path):
    run = RunFolder(tmp_path)
    run.checkpoints.mkdir()
    for step in (10, 9, 1000):
        run.checkpoint(step).write_bytes(b"")
    (run.checkpoints / "best.pt").write_bytes(b"")
    assert sorted(checkpoint_name(s) for s in (10, 9, 1000)) == [checkpoint_name(s) for s in (9, 10, 1000)]
    assert [step for step, _ in list_checkpoints(run.checkpoints)] == [9, 10, 1000]
    assert (
        CHECKPOINT_NAME.match("best.pt") is None and CHECKPOINT_NAME.match(checkpoint_name(7)).group(1) == "000000007"
    )


def test_earlier_histories_are_numbered_from_the_first_free_one(tmp_path):
    run = RunFolder(tmp_path)
    assert run.next_earlier() == tmp_path / "earlier-1"
    run.earlier(1).mkdir()
    run.earlier(3).mkdir()
    assert run.next_earlier() == tmp_path / "earlier-2"
