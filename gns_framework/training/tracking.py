"""Where training metrics go. The default appends JSON lines to ``<run>/metrics.jsonl``."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Protocol


class Tracker(Protocol):
    def log_params(self, params: dict) -> None: ...

    def log_metrics(self, metrics: dict[str, float], step: int) -> None: ...

    def log_artifact(self, path: Path) -> None: ...

    def close(self) -> None: ...


class JsonlTracker:
    """Appends ``{"step": s, "time": t, <metric>: value}`` lines; params go to ``params.json``."""

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._metrics = open(self.run_dir / "metrics.jsonl", "a")

    def log_params(self, params: dict) -> None:
        (self.run_dir / "params.json").write_text(json.dumps(params, indent=2, default=str) + "\n")

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        self._metrics.write(json.dumps({"step": step, "time": time.time(), **metrics}) + "\n")
        self._metrics.flush()

    def log_artifact(self, path: Path) -> None:
        """Artifacts already live in the run folder."""

    def close(self) -> None:
        self._metrics.close()


def read_metrics(run_dir: Path) -> list[dict]:
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
