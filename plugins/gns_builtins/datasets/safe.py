"""The safe layout: plain numeric arrays in ``<split>.npz`` plus ``metadata.json``; no pickle.

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
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gns_framework.contracts import ComponentParams
from gns_framework.data.atomic import atomic_path, write_text_atomic
from gns_framework.data.lazy import TrajectorySequence
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError

from ._formats.npz_common import NpzSplitsDataset, open_npz, read_member

FIELDS = ("position", "particle_type", "material_property", "step_context", "bounds", "walls")


class SafeDataset(NpzSplitsDataset):
    """Pickle-free layout that every tool can read with ``numpy.load(allow_pickle=False)``."""

    name = "safe"
    writable = True

    class Params(ComponentParams):
        pass

    def split(self, name: str) -> Sequence[Trajectory]:
        file = self.path / f"{name}.npz"
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

        def load(key: str) -> Trajectory:
            fields = groups[key]
            get = lambda f: read_member(archive, file, f"{key}/{f}") if f in fields else None  # noqa: E731
            return Trajectory(  # position and particle_type: present (checked above)
                read_member(archive, file, f"{key}/position"),
                read_member(archive, file, f"{key}/particle_type"),
                get("material_property"),
                get("step_context"),
                key,
                get("bounds"),
                get("walls"),
            )

        # File order is the order the trajectories were written in (``gns generate``: seed order), which
        # re-simulating a test case relies on; sorting the keys would lose it.
        return TrajectorySequence(list(groups), load, str(file), self.metadata().dim)

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        path = Path(path)
        for split, trajectories in splits.items():
            arrays: dict[str, Any] = {}  # Any: numpy's stub would match **arrays to savez_compressed's allow_pickle too
            for index, traj in enumerate(trajectories):
                key = traj.key or f"trajectory_{index:05d}"
                arrays[f"{key}/position"] = np.asarray(traj.position, dtype=np.float32)
                arrays[f"{key}/particle_type"] = np.asarray(traj.particle_type, dtype=np.int64)
                if traj.material_property is not None:
                    arrays[f"{key}/material_property"] = np.asarray(traj.material_property, dtype=np.float32)
                for name in ("step_context", "bounds", "walls"):
                    if getattr(traj, name) is not None:
                        arrays[f"{key}/{name}"] = np.asarray(getattr(traj, name), dtype=np.float32)
            with atomic_path(path / f"{split}.npz", suffix=".npz") as tmp:
                np.savez_compressed(tmp, **arrays)
        write_text_atomic(path / "metadata.json", json.dumps(metadata.to_json_dict(), indent=2) + "\n")
