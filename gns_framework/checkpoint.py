"""Checkpoints: written atomically, loaded with ``weights_only=True``, and self-describing.

A checkpoint holds the model, optimizer and schedule state, the step, RNG states,
the resolved recipe, the scene, the dataset metadata and the plugin versions, so a
run can be rebuilt and resumed exactly without the recipe file.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import torch

from .data.atomic import atomic_path
from .errors import CheckpointError

FORMAT = "gns-framework/checkpoint-v1"
_NAME = re.compile(r"^checkpoint-(\d{9})\.pt$")
_PARTIAL = re.compile(r"^\.checkpoint-\d{9}\.pt\..+\.tmp\.pt$")
REQUIRED = ("format", "model", "step", "recipe", "scene", "metadata", "plugins")


def checkpoint_name(step: int) -> str:
    return f"checkpoint-{step:09d}.pt"


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (see REQUIRED) to ``path`` atomically: a crash leaves the old file intact."""
    path = Path(path)
    missing = [k for k in REQUIRED if k != "format" and k not in state]
    if missing:
        raise CheckpointError(f"{path}: refusing to save a checkpoint without {', '.join(missing)}")
    with atomic_path(path, suffix=".pt") as tmp:
        torch.save({"format": FORMAT, **state}, tmp)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint safely (no code from the file runs); clear errors for bad files."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:
        # A damaged file can fail anywhere in the unpickler (KeyError, IndexError, struct.error, ...).
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0]}" if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: unreadable checkpoint (truncated, corrupt or not a checkpoint): {reason}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(
            f"{path}: format: expected {FORMAT!r}, got {found!r} (a geoelements/gns checkpoint? "
            "convert it with `gns import-geoelements`)"
        )
    missing = [k for k in REQUIRED if k not in state]
    if missing:
        raise CheckpointError(f"{path}: missing {', '.join(missing)}")
    return state


def list_checkpoints(directory: str | Path) -> list[tuple[int, Path]]:
    """(step, path) of the checkpoints in ``directory``, oldest first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := _NAME.match(p.name))]
    return sorted(found)


def prune_checkpoints(directory: str | Path, keep: int) -> None:
    """Delete all but the newest ``keep`` checkpoints, and partial writes a killed process left behind.

    Only the run's single writer (rank 0) may call this: another writer's partial
    file would look abandoned.
    """
    for _, path in list_checkpoints(directory)[:-keep]:
        path.unlink(missing_ok=True)
    for path in Path(directory).glob(".checkpoint-*"):
        if _PARTIAL.match(path.name):
            path.unlink(missing_ok=True)


def latest_good_checkpoint(directory: str | Path) -> tuple[Path, dict[str, Any]] | None:
    """The newest checkpoint that loads; damaged newer ones are reported and skipped."""
    for _, path in reversed(list_checkpoints(directory)):
        try:
            return path, load_checkpoint(path)
        except CheckpointError as exc:
            warnings.warn(f"skipping damaged checkpoint: {exc}", stacklevel=2)
    return None
