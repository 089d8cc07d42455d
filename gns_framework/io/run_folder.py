"""The layout of a training run's folder, in one place: every command finds a run's files through it.

::

    <run>/
        checkpoints/checkpoint-<step>.pt   resumable checkpoints (newest kept, see keep_checkpoints)
        checkpoints/best.pt, best.json     the best by validation rollout, and its score
        recipe.yaml, params.json           the resolved recipe and the logged parameters
        metrics.jsonl                      every logged metric, one JSON object per line
        mlflow_run.json                    the MLflow run it logs to (when tracked)
        mlflow_unsent.json                 what MLflow missed at the end (gns track-sync sends it)
        .gns-train.lock                    held by the one gns train writing here
        rollouts/                          gns rollout's default output
        earlier-<n>/                       an earlier history, moved aside by --restart
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from .owned_files import refuse_link

CHECKPOINT_NAME = re.compile(r"^checkpoint-(\d{9})\.pt$")
"""A resumable checkpoint's file name; the step is group 1 (9 digits, so names sort by step)."""


def checkpoint_name(step: int) -> str:
    return f"checkpoint-{step:09d}.pt"


def _below(name: str, folder: str = "root") -> property:
    """A read-only ``Path``: the entry named by the class constant ``name`` inside the run's ``folder``."""
    return property(lambda run: getattr(run, folder) / getattr(run, name), doc=f"<{folder}>/{name}")


@dataclass(frozen=True)
class RunFolder:
    """The files of the run in ``root``."""

    root: Path

    CHECKPOINTS = "checkpoints"
    BEST_CHECKPOINT = "best.pt"
    BEST_RECORD = "best.json"
    RECIPE = "recipe.yaml"
    PARAMS = "params.json"
    METRICS = "metrics.jsonl"
    MLFLOW_RUN = "mlflow_run.json"
    MLFLOW_UNSENT = "mlflow_unsent.json"
    LOCK = ".gns-train.lock"
    ROLLOUTS = "rollouts"

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root))

    @classmethod
    def of_checkpoint(cls, checkpoint: str | Path) -> RunFolder:
        """The run a checkpoint file belongs to: the folder above its ``checkpoints/``."""
        return cls(Path(checkpoint).parent.parent)

    checkpoints = _below("CHECKPOINTS")
    best_checkpoint = _below("BEST_CHECKPOINT", "checkpoints")
    best_record = _below("BEST_RECORD", "checkpoints")
    recipe = _below("RECIPE")
    params = _below("PARAMS")
    metrics = _below("METRICS")
    mlflow_run = _below("MLFLOW_RUN")
    mlflow_unsent = _below("MLFLOW_UNSENT")
    lock = _below("LOCK")
    rollouts = _below("ROLLOUTS")

    def checkpoint(self, step: int) -> Path:
        """``checkpoints/checkpoint-<step, 9 digits>.pt``: names sort by step."""
        return self.checkpoints / checkpoint_name(step)

    def refuse_links(self) -> None:
        """Refuse a run folder whose own files or folders are symbolic links (LinkRefused naming the first).

        A run writes into these; through a link it would write outside the folder. The
        open of each file refuses a link again (``owned_files``), so a link made after
        this check is caught too.
        """
        owned = {
            self.CHECKPOINTS: "checkpoints folder",
            self.ROLLOUTS: "rollouts folder",
            self.RECIPE: "recipe record",
            self.PARAMS: "parameters file",
            self.METRICS: "metrics file",
            self.MLFLOW_RUN: "MLflow run record",
            self.MLFLOW_UNSENT: "MLflow unsent record",
        }
        for name, what in owned.items():
            refuse_link(self.root / name, f"run's {what}")
        if self.checkpoints.is_dir():
            for name in (self.BEST_CHECKPOINT, self.BEST_RECORD):
                refuse_link(self.checkpoints / name, f"run's {name}")

    def earlier(self, number: int) -> Path:
        """``earlier-<number>/``: where ``--restart`` moves the ``number``-th earlier history."""
        return self.root / f"earlier-{number}"

    def next_earlier(self) -> Path:
        """The first ``earlier-<n>/`` that does not exist yet."""
        number = 1
        while self.earlier(number).exists():
            number += 1
        return self.earlier(number)
