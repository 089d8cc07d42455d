"""geoelements/gns layout: ``<split>.npz`` of pickled ``(positions, particle_type[, material_property])`` tuples.

Each member (``simulation_trajectory_<i>``) is a NumPy object array, stored as a
pickle, and unpickling can run code stored in the file. geoelements' pickles hold
numpy arrays only, so they are never unpickled: :mod:`._formats.array_pickle`
reads the pickle's opcodes itself, builds each plain numeric array from a checked
dtype, shape and byte count, and refuses everything else. A file that needs more is
read by numpy only when the user grants it for its folder on the command line
(``--allow-pickle FOLDER``); a recipe or a checkpoint never grants it.

geoelements' ``metadata.json`` is DeepMind's: ``sequence_length`` = T - 1 (steps),
where gns-framework counts frames (T); the layout converts both ways.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gns_framework.api import (
    DatasetError,
    DatasetMetadata,
    Trajectory,
    TrajectorySequence,
    write_text_atomic,
)

from ._formats.npz_common import NpzSplitsDataset, open_npz, read_array_pickle


class GeoelementsNpzDataset(NpzSplitsDataset):
    """Datasets written by geoelements/gns (e.g. its Sand, WaterDrop conversions)."""

    name = "npz"
    writable = True

    def metadata(self) -> DatasetMetadata:
        stored = super().metadata()
        return stored.model_copy(update={"sequence_length": stored.sequence_length + 1})

    def split(self, name: str) -> Sequence[Trajectory]:
        file = self.split_file(name)
        archive = open_npz(file, allow_pickle=self.allow_pickle)
        metadata = self.metadata()

        def load(key: str) -> Trajectory:
            item = read_array_pickle(archive, file, key)
            if item.dtype != object or item.ndim != 1 or len(item) not in (2, 3):
                raise DatasetError(
                    f"{file}: trajectory {key!r}: expected a (positions, particle_type[, material_property]) "
                    f"tuple, got an array of dtype {item.dtype} and shape {item.shape}"
                )
            return Trajectory(
                np.asarray(item[0]), np.asarray(item[1]), np.asarray(item[2]) if len(item) == 3 else None, key=key
            )

        return TrajectorySequence(
            list(archive.files), load, str(file), metadata.domain_check(), keep=self.keep_trajectories
        )

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        path = Path(path)
        cls.write_split_files(path, splits, _geoelements_item, lambda file, arrays: np.savez_compressed(file, **arrays))
        document = {**metadata.to_json_dict(), "sequence_length": metadata.sequence_length - 1}
        write_text_atomic(path / "metadata.json", json.dumps(document, indent=2) + "\n")


def _geoelements_item(file: Path, index: int, traj: Trajectory) -> dict[str, Any]:
    """A trajectory as geoelements stores it: one object array (positions, types[, material property])."""
    if traj.step_context is not None:
        raise DatasetError(f"{file}: {traj.key}: the geoelements layout has no step_context")
    fields = [np.asarray(traj.position, np.float32), np.asarray(traj.particle_type, np.int64)]
    if traj.material_property is not None:
        prop = np.asarray(traj.material_property, np.float32)
        fields.append(prop[:, 0] if prop.shape[1] == 1 else prop)
    item = np.empty(len(fields), dtype=object)
    item[:] = fields
    return {traj.key or f"simulation_trajectory_{index}": item}
