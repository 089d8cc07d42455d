"""MLflow tracking options of ``gns train`` and ``gns invert`` (``gns_framework.cli.tracking_options``): the local
metrics file always, MLflow beside it unless tracking is off, mlflow is missing or the server is unreachable at the
start (a warning, never a wait). The MLflow calls are stand-ins here; tests/training/test_mlflow_tracker.py runs
real ones."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import pytest

from gns_framework.cli.tracking_options import add_tracking_arguments, check_tracking_arguments, with_mlflow
from gns_framework.training import mlflow_tracker
from gns_framework.training.tracking import TrackerGroup


class Local:
    """The run folder's metrics file, as far as ``with_mlflow`` sees it."""


class FakeMlflow:
    run_id = "0123abcd"


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_tracking_arguments(parser, "<run>/metrics.jsonl", "the recipe's name")
    return parser.parse_args(list(argv))


class Server:
    """The ``open_mlflow_tracker`` calls made; the server answers unless ``error`` is set."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.error: Exception | None = None

    def open(self, run_dir, uri, experiment, resume):
        self.calls.append((run_dir, uri, experiment, resume))
        if self.error is not None:
            raise self.error
        return FakeMlflow()


class Refused(Exception):
    """A request the server answered with a refusal (a 4xx): not worth trying again later."""


@pytest.fixture
def opened(monkeypatch):
    server = Server()
    monkeypatch.setattr(mlflow_tracker, "open_mlflow_tracker", server.open)
    monkeypatch.setattr(mlflow_tracker, "mlflow_available", lambda: True)
    monkeypatch.setattr(mlflow_tracker, "default_tracking_uri", lambda: "sqlite:///default.db")
    monkeypatch.setattr(mlflow_tracker, "server_unreachable", lambda error: isinstance(error, ConnectionError))
    return server


def test_the_options_default_to_tracking_with_the_default_store():
    args = parse()
    assert (args.tracking_uri, args.experiment, args.no_tracking) == (None, None, False)
    args = parse("--tracking-uri", "http://host:5000", "--experiment", "sand", "--no-tracking")
    assert (args.tracking_uri, args.experiment, args.no_tracking) == ("http://host:5000", "sand", True)


def test_no_tracking_keeps_the_local_file_alone(opened):
    local = Local()
    assert with_mlflow(parse("--no-tracking"), "tiny", Path("run"), local, resume=False) is local
    assert opened.calls == []


def test_an_answering_server_tracks_beside_the_local_file(opened, capsys):
    local = Local()
    tracker = with_mlflow(parse(), "tiny", Path("run"), local, resume=True)
    assert isinstance(tracker, TrackerGroup) and tracker.trackers[0] is local
    assert isinstance(tracker.trackers[1], FakeMlflow)
    # No --tracking-uri: the default store; no --experiment: the default name the command passes.
    assert opened.calls == [(Path("run"), "sqlite:///default.db", "tiny", True)]
    assert capsys.readouterr().out == "tracking run 0123abcd in sqlite:///default.db\n"
    with_mlflow(parse("--tracking-uri", "http://host:5000", "--experiment", "sand"), "tiny", Path("r"), local, False)
    assert opened.calls[-1] == (Path("r"), "http://host:5000", "sand", False)


def test_without_mlflow_installed_the_metrics_go_to_the_run_folder_only(opened, monkeypatch, capsys):
    monkeypatch.setattr(mlflow_tracker, "mlflow_available", lambda: False)
    local = Local()
    assert with_mlflow(parse(), "tiny", Path("run"), local, resume=False) is local
    assert "mlflow is not installed: metrics go to the run folder only" in capsys.readouterr().out
    assert opened.calls == []
    # A URI given on the command line is a request to track: then a missing mlflow is the error MLflow gives.
    with_mlflow(parse("--tracking-uri", "http://host:5000"), "tiny", Path("run"), local, resume=False)
    assert opened.calls[-1][1] == "http://host:5000"


def test_an_unreachable_server_is_a_warning_and_the_run_goes_on_untracked(opened):
    opened.error = ConnectionError("connection refused\nTraceback (most recent call last): ...")
    local = Local()
    with pytest.warns(UserWarning) as caught:
        tracker = with_mlflow(
            parse("--tracking-uri", "http://host:5000"), "inv", Path("out"), local, False, "the inversion"
        )
    assert tracker is local
    (message,) = [str(w.message) for w in caught]
    assert message == (
        "tracking: MLflow at http://host:5000 unreachable (connection refused); the inversion goes on without it, "
        f"the metrics go to {Path('out') / 'metrics.jsonl'} only"
    )


def test_a_server_that_refuses_the_request_is_an_error(opened):
    opened.error = Refused("403: not allowed")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning first: the error alone
        with pytest.raises(mlflow_tracker.TrackingError, match=r"^MLflow at sqlite:///default\.db: 403: not allowed$"):
            with_mlflow(parse(), "tiny", Path("run"), Local(), resume=False)


@pytest.mark.parametrize("uri", ["http://[::1", "ftp://example.org/x", "sqlite://no-third-slash.db"])
def test_train_refuses_a_malformed_tracking_uri_in_one_line_and_leaves_no_folder(tmp_path, capsys, uri):
    from gns_framework.cli import main

    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("name: x\n")
    out = tmp_path / "run"
    assert main(["train", str(recipe), "--out", str(out), "--tracking-uri", uri]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"gns train: error: --tracking-uri {uri!r}: ") and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_the_environment_s_tracking_uri_is_checked_too(monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "ftp://example.org/x")
    with pytest.raises(
        mlflow_tracker.TrackingError, match=r"^\$MLFLOW_TRACKING_URI 'ftp://example.org/x': unsupported"
    ):
        check_tracking_arguments(parse())
    check_tracking_arguments(parse("--no-tracking"))
