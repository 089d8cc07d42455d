"""Checkpoints: written atomically, verified and loaded with ``weights_only=True``, self-describing, never lost.

A checkpoint holds the model, optimizer and schedule state, the step, RNG states,
the resolved recipe, the scene, the dataset metadata and, per component, the
distribution and version that provided it (``plugins``), so a run can be rebuilt and
resumed exactly without the recipe file, and a missing component named with the
``pip install`` that brings it back.

A checkpoint is a zip archive (``torch.save``) whose every record carries a CRC-32,
and save_checkpoint adds one record more, the SHA-256 of all the others. torch.load
checks neither: one flipped byte in a tensor loads silently as a different weight.
load_checkpoint verifies both first (the CRCs alone for checkpoints written before
the digest) and refuses a damaged file by name.

Training never deletes or overwrites a checkpoint of another history, nor a damaged
one: a run folder holds one history, resumed only from its newest good checkpoint
(resume_point) and started afresh only when it holds none or once they are moved
aside (make_room_for_a_fresh_start); a damaged checkpoint is renamed, never replaced
(set_aside_damaged).
"""

from __future__ import annotations

import hashlib
import os
import re
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from ..data.atomic import atomic_path, fsync_directory
from ..errors import CheckpointError
from .run_folder import CHECKPOINT_NAME, RunFolder

FORMAT = "gns-framework/checkpoint-v1"
_PARTIAL = re.compile(r"^\.checkpoint-\d{9}\.pt\..+\.tmp\.pt$")
REQUIRED = ("format", "model", "step", "recipe", "scene", "metadata", "plugins")
DIGEST_RECORD = "gns_sha256"
"""Name (inside the archive's folder) of the record holding the SHA-256 of the other records, in hex."""
HISTORY_RECORD = "gns_history"
"""Name of the record holding the id of the training history that wrote the checkpoint (read without unpickling)."""
DAMAGED_SUFFIX = ".damaged"
UNREADABLE = "unreadable checkpoint (truncated, corrupt or not a checkpoint)"


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (see REQUIRED) to ``path`` atomically: a crash leaves the old file intact."""
    path = Path(path)
    missing = [k for k in REQUIRED if k != "format" and k not in state]
    if missing:
        raise CheckpointError(f"{path}: refusing to save a checkpoint without {', '.join(missing)}")
    with atomic_path(path, suffix=".pt") as tmp:
        torch.save({"format": FORMAT, **state}, tmp)
        with zipfile.ZipFile(tmp, "a") as archive:
            folder = archive.infolist()[0].filename.split("/")[0]
            if isinstance(state.get("history"), str):
                archive.writestr(f"{folder}/{HISTORY_RECORD}", state["history"])
            computed, _ = _record_digest(archive)
            archive.writestr(f"{folder}/{DIGEST_RECORD}", computed)
    return path


def _record_digest(archive: zipfile.ZipFile) -> tuple[str, str | None]:
    """(SHA-256 of every record's name, size and bytes but the digest's, the stored digest or None).

    Reading a record through zipfile also checks its CRC-32; a record that fails
    to read raises _DamagedRecord.
    """
    digest, stored = hashlib.sha256(), None
    for info in archive.infolist():
        try:
            with archive.open(info) as record:
                if info.filename.rsplit("/", 1)[-1] == DIGEST_RECORD:
                    stored = record.read().decode("ascii", errors="replace")
                    continue
                digest.update(f"{info.filename}\0{info.file_size}\0".encode())
                while chunk := record.read(1 << 20):
                    digest.update(chunk)
        except Exception as exc:
            # zipfile reports a CRC mismatch as BadZipFile; damaged headers fail in many other ways.
            raise _DamagedRecord(info.filename.split("/", 1)[-1], exc) from None
    return digest.hexdigest(), stored


class _DamagedRecord(Exception):
    """A record of the archive that fails to read, named without the archive's folder (the temporary file's name)."""

    def __init__(self, name: str, cause: Exception):
        crc = isinstance(cause, zipfile.BadZipFile) and "CRC" in str(cause)
        super().__init__(f"record {name} does not match its CRC-32" if crc else f"record {name}: {cause}")


def verify_checkpoint(path: str | Path) -> None:
    """Refuse ``path`` unless its records match the CRC-32s and the SHA-256 written with them."""
    path = Path(path)
    if not zipfile.is_zipfile(path):
        raise CheckpointError(f"{path}: {UNREADABLE}: not a zip archive")
    damaged = f"{path}: damaged checkpoint, its bytes changed after it was written"
    try:
        with zipfile.ZipFile(path) as archive:
            computed, stored = _record_digest(archive)
    except (_DamagedRecord, zipfile.BadZipFile, OSError, ValueError, NotImplementedError, EOFError) as exc:
        # A damaged central directory can claim a zip version or compression zipfile lacks (NotImplementedError).
        raise CheckpointError(f"{damaged}: {exc}") from None
    if stored is not None and stored != computed:
        raise CheckpointError(f"{damaged}: SHA-256 {computed} differs from {stored!r} written with it")


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint safely (no code from the file runs); clear errors for bad files."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"{path}: a directory, not a checkpoint file; {_contents(path)}")
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    verify_checkpoint(path)
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:
        # A damaged file can fail anywhere in the unpickler (KeyError, IndexError, struct.error, ...).
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0]}" if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: {UNREADABLE}: {reason}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(
            f"{path}: format: expected {FORMAT!r}, got {found!r} (a geoelements/gns checkpoint? "
            "convert it with `gns import-geoelements`)"
        )
    missing = [k for k in REQUIRED if k not in state]
    if missing:
        raise CheckpointError(f"{path}: missing {', '.join(missing)}")
    _check_fields(path, state)
    return state


def _check_fields(path: Path, state: dict[str, Any]) -> None:
    """Refuse, by field, a checkpoint whose digest matches but whose records are not what gns train writes.

    A checkpoint re-signed after editing (or written by other code) passes the
    digest; its fields are then checked here, so a bad step or recipe is one line
    naming the field instead of a ValueError or KeyError deep in loading.
    """
    step = state["step"]
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise CheckpointError(f"{path}: step: expected a whole number >= 0, got {_short(step)}")
    for key in ("recipe", "scene", "metadata", "plugins", "model"):
        if not isinstance(state[key], dict):
            raise CheckpointError(
                f"{path}: {key}: expected a mapping, got {type(state[key]).__name__} {_short(state[key])}"
            )
    if not isinstance(state["recipe"].get("model", {}), dict):
        raise CheckpointError(f"{path}: recipe.model: expected a mapping, got {_short(state['recipe']['model'])}")
    for key in ("optimizer", "scheduler", "rng", "best", "envelope"):
        if key in state and not isinstance(state[key], dict):
            raise CheckpointError(
                f"{path}: {key}: expected a mapping, got {type(state[key]).__name__} {_short(state[key])}"
            )
    if "history" in state and not isinstance(state["history"], str):
        raise CheckpointError(f"{path}: history: expected a string, got {_short(state['history'])}")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _contents(directory: Path) -> str:
    """What a directory given as a checkpoint holds, in words: its checkpoints, or its run's."""
    if names := _held(directory):
        return f"it holds {', '.join(names)}: name one of them"
    if names := _held(RunFolder(directory).checkpoints):
        return (
            f"a run folder, whose checkpoints/ holds {', '.join(names)}: name one of them, or resume the newest "
            f"with --out {directory} --resume"
        )
    return "it holds no checkpoints (*.pt)"


def list_checkpoints(directory: str | Path) -> list[tuple[int, Path]]:
    """(step, path) of the checkpoints in ``directory``, oldest first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := CHECKPOINT_NAME.match(p.name))]
    return sorted(found)


def checkpoint_history(path: str | Path) -> str | None:
    """The id of the training history that wrote ``path`` (None: written before histories were recorded, or unreadable).

    Read from one small record of the archive, so it costs no unpickling.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if info.filename.rsplit("/", 1)[-1] == HISTORY_RECORD and info.file_size <= 256:
                    return archive.read(info).decode("ascii")
    except Exception:
        return None
    return None


def prune_checkpoints(directory: str | Path, keep: int, history: str | None = None) -> list[Path]:
    """Delete all but the newest ``keep`` checkpoints of ``history``, and partial writes a killed process left behind.

    Only checkpoints whose recorded history is ``history`` count and may go: a
    checkpoint of another history (one copied in to resume from, or the folder's
    earlier run), or one that records none, is never deleted. A checkpoint due to go
    is verified first: a damaged one is renamed aside (``.damaged``), never deleted.
    Returns the paths set aside. Only the run's single writer (rank 0, holding the
    run folder's lock) may call this: another writer's partial file would look abandoned.
    """
    set_aside: list[Path] = []
    own = [p for _, p in list_checkpoints(directory) if history is not None and checkpoint_history(p) == history]
    for path in own[:-keep] if keep > 0 else own:
        try:
            verify_checkpoint(path)
        except CheckpointError as exc:
            target = set_aside_damaged(path)
            warnings.warn(f"retention kept a damaged checkpoint as {target.name}: {exc}", stacklevel=2)
            set_aside.append(target)
            continue
        path.unlink(missing_ok=True)
    for path in Path(directory).glob(".checkpoint-*"):
        if _PARTIAL.match(path.name):
            path.unlink(missing_ok=True)
    return set_aside


def latest_good_checkpoint(directory: str | Path) -> tuple[Path, dict[str, Any]] | None:
    """The newest checkpoint that loads, None when there is none; damaged newer ones are reported and skipped.

    When every checkpoint is damaged, starting at step 0 instead would write over
    them by name and prune them: that is refused, naming each, and none is touched.
    """
    damaged: list[CheckpointError] = []
    for _, path in reversed(list_checkpoints(directory)):
        try:
            found = path, load_checkpoint(path)
        except CheckpointError as exc:
            damaged.append(exc)
            continue
        for error in damaged:
            warnings.warn(f"skipping damaged checkpoint: {error}", stacklevel=2)
        return found
    if damaged:
        reasons = "\n".join(f"  {exc}" for exc in damaged)
        raise CheckpointError(
            f"{directory}: every checkpoint is damaged, nothing to resume from (all are left as they are):\n{reasons}\n"
            "resume from a good copy with --resume PATH, or start afresh with --restart (moves them aside)"
        )
    return None


@dataclass
class ResumePoint:
    """The checkpoint a run continues from, and the damaged newer ones of its folder to set aside once it has."""

    path: Path
    state: dict[str, Any]
    damaged_newer: list[Path] = field(default_factory=list)


def resume_point(directory: str | Path, checkpoint: str | Path | None = None) -> ResumePoint | None:
    """Where a run writing its checkpoints to ``directory`` resumes: ``checkpoint``, else the newest good one there.

    Refused, naming the files, when continuing would cost a checkpoint of another
    history: retention keeps the newest by step number, and a step's file name is
    the same in every history, so resuming before the newest good checkpoint of
    ``directory`` would overwrite and prune the newer ones, and resuming from
    elsewhere into a folder that holds checkpoints would prune those. Such a
    branch goes to a run folder of its own (``--out``). Damaged newer checkpoints
    are no history to keep going: they are listed to be set aside.
    """
    directory = Path(directory)
    if checkpoint is None:
        found = latest_good_checkpoint(directory)
        if found is None:
            return None
        path, state = found
    else:
        path = Path(checkpoint)
        state = load_checkpoint(path)
    held = list_checkpoints(directory)
    if path.resolve().parent != directory.resolve():
        if held:
            raise CheckpointError(
                f"{path}: resuming from outside {directory}, which holds checkpoints of another history "
                f"({', '.join(p.name for _, p in held)}) that this run's would overwrite and prune: "
                f"copy {path.name} into it, or give this run an empty folder with --out"
            )
        return ResumePoint(path, state)
    step = int(state["step"])
    newer = [p for s, p in held if s > step]
    damaged = [p for p in newer if not _loads(p)]
    if len(damaged) < len(newer):
        raise CheckpointError(
            f"{path}: resuming at step {step} would overwrite and prune the newer checkpoints of {directory} "
            f"({', '.join(p.name for p in newer if p not in damaged)}): resume from the newest (--resume without a "
            f"path), or branch into a run folder of its own with --out DIR --resume {path}"
        )
    return ResumePoint(path, state, damaged)


def _loads(path: Path) -> bool:
    try:
        load_checkpoint(path)
    except CheckpointError:
        return False
    return True


def set_aside_damaged(path: Path) -> Path:
    """Rename a damaged checkpoint to ``<name>.damaged`` (numbered when taken): a run never writes over one."""
    target = path.with_name(path.name + DAMAGED_SUFFIX)
    number = 1
    while target.exists():
        number += 1
        target = path.with_name(f"{path.name}{DAMAGED_SUFFIX}-{number}")
    os.rename(path, target)
    fsync_directory(path.parent)
    return target


def make_room_for_a_fresh_start(run: RunFolder, restart: bool) -> Path | None:
    """Let a run start at step 0 writing to ``run``'s checkpoints; returns where earlier checkpoints went, if anywhere.

    A run started afresh where another left checkpoints would write over them by
    name and prune them. Without ``restart`` that is refused, naming them; with it,
    the checkpoint folder and the earlier run's MLflow record (when there is one)
    move whole into ``<run>/earlier-<n>/``, where the checkpoints keep their names
    and still load, roll out and report to the run that trained them.
    """
    checkpoint_dir = run.checkpoints
    held = _held(checkpoint_dir)
    if not held:
        return None
    if not restart:
        raise CheckpointError(
            f"{checkpoint_dir}: holds checkpoints of an earlier run ({', '.join(held)}) that starting at step 0 "
            "would overwrite and prune: continue it with --resume, start afresh with --restart (moves them to "
            "earlier-N/ in the run folder), or use another run folder (--out)"
        )
    earlier = run.next_earlier()
    earlier.mkdir()
    for path in [checkpoint_dir, run.mlflow_run]:
        if path.exists():
            try:
                os.rename(path, earlier / path.name)
            except OSError as exc:
                raise CheckpointError(f"{path}: could not move it to {earlier}: {exc}") from None
    fsync_directory(earlier)
    fsync_directory(run.root)
    return earlier


def _held(folder: Path) -> list[str]:
    """Names of the checkpoints in ``folder``, numbered or not (partial writes start with a dot)."""
    return sorted(p.name for p in folder.glob("*.pt") if not p.name.startswith(".")) if folder.is_dir() else []
