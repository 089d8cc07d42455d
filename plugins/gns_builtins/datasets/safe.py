"""The safe layout: plain numeric arrays in ``<split>.npz`` plus ``metadata.json``; no pickle.

Positions are stored uncompressed and the other members compressed (older files:
all compressed; both read the same). Uncompressed positions are memory-mapped under
``dataset.memory: windows``.

Layout of ``<split>.npz`` (one group of members per trajectory, keys sorted)::

    <key>/position           (T, N, d) float32
    <key>/particle_type      (N,) int64
    <key>/material_property  (N, P) float32   optional
    <key>/step_context       (T, C) float32   optional
    <key>/bounds             (d, 2) float32   optional: this trajectory's domain (default metadata.bounds)
    <key>/walls              (2d, 2) float32  optional: friction and no-slip flag of each face
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gns_framework.api import (
    DatasetError,
    DatasetMetadata,
    Trajectory,
    TrajectorySequence,
    mapped_member,
    write_text_atomic,
)

from ._formats.npz_common import NpzSplitsDataset, open_npz, read_member

FIELDS = ("position", "particle_type", "material_property", "step_context", "bounds", "walls")


class SafeDataset(NpzSplitsDataset):
    """Pickle-free layout that every tool can read with ``numpy.load(allow_pickle=False)``."""

    name = "safe"
    writable = True

    def split(self, name: str) -> Sequence[Trajectory]:
        file = self.split_file(name)
        archive = open_npz(file)
        groups: dict[str, set[str]] = {}
        for member in archive.files:
            key, _, field = member.rpartition("/")
            if not key or field not in FIELDS:
                raise DatasetError(f"{file}: member {member!r}: expected '<trajectory>/<field>' with field in {FIELDS}")
            groups.setdefault(key, set()).add(field)
        for key, fields in groups.items():
            for required in ("position", "particle_type"):
                if required not in fields:
                    raise DatasetError(f"{file}: trajectory {key!r}: {required}: missing")

        # dataset.memory: windows maps each position member, so a process reads the frames of its windows.
        mapped = self.keep_trajectories is not None

        def load(key: str) -> Trajectory:
            fields = groups[key]
            get = lambda f: read_member(archive, file, f"{key}/{f}") if f in fields else None  # noqa: E731
            position = mapped_member(file, archive.zip, f"{key}/position") if mapped and archive.zip else None
            return Trajectory(  # position and particle_type: present (checked above)
                read_member(archive, file, f"{key}/position") if position is None else position,
                read_member(archive, file, f"{key}/particle_type"),
                get("material_property"),
                get("step_context"),
                key,
                get("bounds"),
                get("walls"),
            )

        # File order is the order the trajectories were written in (``gns generate``: seed order), which
        # re-simulating a test case relies on; sorting the keys would lose it.
        metadata = self.metadata()
        return TrajectorySequence(list(groups), load, str(file), metadata.domain_check(), keep=self.keep_trajectories)

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        path = Path(path)
        cls.write_split_files(path, splits, _members, _write_npz)
        write_text_atomic(path / "metadata.json", json.dumps(metadata.to_json_dict(), indent=2) + "\n")


def _members(file: Path, index: int, traj: Trajectory) -> dict[str, Any]:
    """A trajectory's plain arrays, ``<key>/<field>``: positions and types, and the optional fields it has."""
    key = traj.key or f"trajectory_{index:05d}"
    arrays: dict[str, Any] = {
        f"{key}/position": np.asarray(traj.position, dtype=np.float32),
        f"{key}/particle_type": np.asarray(traj.particle_type, dtype=np.int64),
    }
    for name in ("material_property", "step_context", "bounds", "walls"):
        if getattr(traj, name) is not None:
            arrays[f"{key}/{name}"] = np.asarray(getattr(traj, name), dtype=np.float32)
    return arrays


def _write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """``arrays`` as an ``.npz`` that ``numpy.load`` reads: positions stored as they are, the rest compressed.

    Positions are most of a dataset and compress little (float32 coordinates); stored
    uncompressed they can be memory-mapped (:func:`~gns_framework.data.npz_mapping.mapped_member`),
    so a training process reads only the frames it uses. Member times are fixed, so the
    same data gives the same file.
    """
    with zipfile.ZipFile(path, "w", allowZip64=True) as archive:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_STORED if name.endswith("/position") else zipfile.ZIP_DEFLATED
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
