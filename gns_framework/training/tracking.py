"""Where training metrics go. The default appends JSON lines to ``<run>/metrics.jsonl``.

Only rank 0 of a distributed run tracks (see distributed.py).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Protocol

from ..io.owned_files import open_owned, write_owned_text
from ..io.run_folder import RunFolder


class Tracker(Protocol):
    def log_params(self, params: dict) -> None: ...

    def log_metrics(self, metrics: dict[str, float], step: int) -> None: ...

    def log_artifact(self, path: Path) -> None: ...

    def close(self, failed: bool = False, killed: bool = False) -> None:
        """End the run: FINISHED, FAILED (an error) or KILLED (stopped by a signal)."""
        ...


class JsonlTracker:
    """Appends ``{"step": s, "time": t, <metric>: value}`` lines; params go to ``params.json``."""

    def __init__(self, run_dir: Path):
        self.run = RunFolder(run_dir)
        self.run.root.mkdir(parents=True, exist_ok=True)
        self._metrics = open_owned(self.run.metrics, "a", "metrics file")

    def log_params(self, params: dict) -> None:
        write_owned_text(self.run.params, json.dumps(params, indent=2, default=str) + "\n", "parameters file")

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        self._metrics.write(json.dumps({"step": step, "time": time.time(), **metrics}) + "\n")
        self._metrics.flush()

    def log_artifact(self, path: Path) -> None:
        """Artifacts already live in the run folder."""

    def close(self, failed: bool = False, killed: bool = False) -> None:
        self._metrics.close()


class TrackerGroup:
    """Sends everything to several trackers (the run folder's JSON lines and MLflow, say)."""

    def __init__(self, trackers: list[Tracker]):
        self.trackers = trackers

    def log_params(self, params: dict) -> None:
        for tracker in self.trackers:
            tracker.log_params(params)

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        for tracker in self.trackers:
            tracker.log_metrics(metrics, step)

    def log_artifact(self, path: Path) -> None:
        for tracker in self.trackers:
            tracker.log_artifact(path)

    def close(self, failed: bool = False, killed: bool = False) -> None:
        for tracker in self.trackers:
            tracker.close(failed, killed)


def read_metrics(run_dir: Path) -> list[dict]:
    path = RunFolder(run_dir).metrics
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
