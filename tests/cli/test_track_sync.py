"""``gns track-sync RUN`` (``gns_framework.cli.track_sync``): what it reports of the sync, and a run it cannot sync
as a one-line error. The sync itself, against a real MLflow store after an outage, is tested end to end in
tests/test_one_line_errors.py and in tests/training/test_mlflow_tracker.py."""

from __future__ import annotations

from pathlib import Path

from gns_framework.cli import main
from gns_framework.training import mlflow_tracker


def test_it_reports_what_was_sent_and_the_status_set(monkeypatch, capsys, tmp_path):
    synced = []
    answers = iter([("0123abcd", 3, "FINISHED"), ("0123abcd", 0, None)])

    def sync_run(run_dir):
        synced.append(run_dir)
        return next(answers)

    monkeypatch.setattr(mlflow_tracker, "sync_run", sync_run)
    run = tmp_path / "run"
    assert main(["track-sync", str(run)]) == 0
    assert capsys.readouterr().out == f"sent 3 metric value(s) of {run} to MLflow run 0123abcd; marked FINISHED\n"
    # Nothing left to send and no status to set: the line says so, without a status.
    assert main(["track-sync", str(run)]) == 0
    assert capsys.readouterr().out == f"sent 0 metric value(s) of {run} to MLflow run 0123abcd\n"
    assert synced == [Path(run), Path(run)]


def test_a_run_never_tracked_with_mlflow_is_a_one_line_error(tmp_path, capsys):
    assert main(["track-sync", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == f"gns track-sync: error: {tmp_path}: no mlflow_run.json: this run was not tracked with MLflow\n"
