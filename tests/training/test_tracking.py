"""The run folder's tracker (JSON lines and params.json), the group that fans out to several trackers, and
reading the metrics back."""

from __future__ import annotations

import json
from pathlib import Path

from gns_framework.training.tracking import JsonlTracker, TrackerGroup, read_metrics


def test_metrics_are_appended_one_json_line_per_log_with_step_and_time(tmp_path):
    run = tmp_path / "runs" / "x"  # created by the tracker
    tracker = JsonlTracker(run)
    tracker.log_metrics({"loss": 0.5, "lr": 1e-4}, step=10)
    tracker.log_metrics({"loss": 0.25}, step=20)
    # Flushed at each log: a reader sees the lines while training goes on.
    lines = read_metrics(run)
    assert [(m["step"], m["loss"]) for m in lines] == [(10, 0.5), (20, 0.25)] and lines[0]["lr"] == 1e-4
    assert lines[0]["time"] <= lines[1]["time"]
    tracker.close()


def test_a_resumed_run_appends_to_the_earlier_lines(tmp_path):
    first = JsonlTracker(tmp_path)
    first.log_metrics({"loss": 1.0}, step=1)
    first.close()
    second = JsonlTracker(tmp_path)
    second.log_metrics({"loss": 0.9}, step=2)
    second.close(failed=True)
    assert [m["step"] for m in read_metrics(tmp_path)] == [1, 2]


def test_params_go_to_params_json_with_anything_unusual_as_text(tmp_path):
    tracker = JsonlTracker(tmp_path)
    tracker.log_params({"lr": 1e-3, "dataset": Path("data/sand")})
    assert json.loads((tmp_path / "params.json").read_text()) == {"lr": 1e-3, "dataset": "data/sand"}
    tracker.log_params({"lr": 2e-3})  # the latest params replace the earlier ones
    assert json.loads((tmp_path / "params.json").read_text()) == {"lr": 2e-3}
    tracker.close()


def test_reading_a_run_without_metrics_gives_none(tmp_path):
    assert read_metrics(tmp_path / "never_trained") == []


def test_reading_skips_blank_lines(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"step": 1}\n\n{"step": 2}\n')
    assert read_metrics(tmp_path) == [{"step": 1}, {"step": 2}]


class Recorder:
    """A tracker that records what it is sent."""

    def __init__(self, name: str, log: list):
        self.name, self.log = name, log

    def log_params(self, params):
        self.log.append((self.name, "params", params))

    def log_metrics(self, metrics, step):
        self.log.append((self.name, "metrics", metrics, step))

    def log_artifact(self, path):
        self.log.append((self.name, "artifact", path))

    def close(self, failed=False, killed=False):
        self.log.append((self.name, "close", failed) + (("killed",) if killed else ()))


def test_a_group_sends_everything_to_each_tracker_in_order():
    log: list = []
    group = TrackerGroup([Recorder("jsonl", log), Recorder("mlflow", log)])
    group.log_params({"lr": 1e-3})
    group.log_metrics({"loss": 0.5}, 7)
    group.log_artifact(Path("best.pt"))
    group.close(failed=True)
    assert log == [
        ("jsonl", "params", {"lr": 1e-3}),
        ("mlflow", "params", {"lr": 1e-3}),
        ("jsonl", "metrics", {"loss": 0.5}, 7),
        ("mlflow", "metrics", {"loss": 0.5}, 7),
        ("jsonl", "artifact", Path("best.pt")),
        ("mlflow", "artifact", Path("best.pt")),
        ("jsonl", "close", True),
        ("mlflow", "close", True),
    ]


def test_the_run_folder_tracker_keeps_no_artifact_of_its_own(tmp_path):
    # Checkpoints already live in the run folder: logging one copies nothing.
    tracker = JsonlTracker(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    tracker.log_artifact(tmp_path / "checkpoints" / "best.pt")
    tracker.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_run_stopped_by_a_signal_closes_every_tracker_as_killed():
    log: list = []
    TrackerGroup([Recorder("jsonl", log), Recorder("mlflow", log)]).close(killed=True)
    assert log == [("jsonl", "close", False, "killed"), ("mlflow", "close", False, "killed")]
