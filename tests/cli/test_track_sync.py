"""``gns track-sync RUN`` (``gns_framework.cli.track_sync``): what it reports of the sync, and a run it cannot sync
as a one-line error. The sync itself, against a real MLflow store after an outage, is tested end to end in
tests/test_one_line_errors.py and in tests/training/test_mlflow_tracker.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gns_framework.cli import main
from gns_framework.training import mlflow_tracker


def test_it_reports_what_was_sent_and_the_status_set(monkeypatch, capsys, tmp_path):
    synced = []
    answers = iter([("0123abcd", 3, "FINISHED"), ("0123abcd", 0, None)])

    def sync_run(run_dir, tracking_uri=None):
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


def _unrelated_database(path: Path) -> bytes:
    import sqlite3

    with sqlite3.connect(path) as connection:
        connection.execute("CREATE TABLE invoices (id INTEGER PRIMARY KEY, total REAL)")
    return path.read_bytes()


def test_the_store_comes_from_the_user_never_from_the_run_folder(tmp_path, capsys, monkeypatch):
    """A run folder whose record points at another database is refused, naming both stores, and that database is
    left as it was; named by the user, a database that is not an MLflow store is refused too."""
    other = tmp_path / "other.db"
    before = _unrelated_database(other)
    run = tmp_path / "run"
    run.mkdir()
    (run / "mlflow_run.json").write_text(json.dumps({"tracking_uri": f"sqlite:///{other}", "run_id": "abc"}))
    (run / "metrics.jsonl").write_text('{"step": 1, "time": 1.0, "train_loss": 0.5}\n')
    mine = f"sqlite:///{tmp_path / 'mine.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", mine)
    assert main(["track-sync", str(run)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"the run was tracked in sqlite:///{other}, but this command's store is {mine}" in err
    assert main(["track-sync", str(run), "--tracking-uri", f"sqlite:///{other}"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"{other} is a database of something else (tables invoices), not an MLflow store" in err
    assert other.read_bytes() == before
    assert not (tmp_path / "mine.db").exists()


@pytest.mark.parametrize(
    ("uri", "says"),
    [
        ("http://[::1", "malformed"),
        ("ftp://example.org/store", "unsupported scheme 'ftp'"),
        ("http://", "no host"),
        ("sqlite://relative.db", "expected sqlite:///path"),
    ],
)
def test_a_malformed_tracking_uri_is_one_line_before_any_store_is_touched(tmp_path, capsys, uri, says):
    run = tmp_path / "run"
    run.mkdir()
    (run / "mlflow_run.json").write_text(json.dumps({"tracking_uri": uri, "run_id": "abc"}))
    assert main(["track-sync", str(run), "--tracking-uri", uri]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and says in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_store_mlflow_will_not_open_is_one_line(tmp_path, capsys, monkeypatch):
    """MLflow 3 refuses file stores unless told otherwise: its refusal is one line, not a traceback."""
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE", raising=False)
    uri = f"file://{tmp_path / 'mlruns'}"
    run = tmp_path / "run"
    run.mkdir()
    (run / "mlflow_run.json").write_text(json.dumps({"tracking_uri": uri, "run_id": "abc"}))
    assert main(["track-sync", str(run), "--tracking-uri", uri]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and f"MLflow cannot open the store {uri}: " in err, err
