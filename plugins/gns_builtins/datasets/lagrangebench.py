"""LagrangeBench's layout (Toshev et al. 2023): ``<split>.h5`` with one group per trajectory, plus ``metadata.json``.

Each group (``00000``, ``00001``, ...) holds ``position`` (T, N, d) and
``particle_type`` (N,). LagrangeBench's metadata differs from DeepMind's:
``dt`` is the solver step and frames are ``write_every`` steps apart,
sequence lengths are per split (``sequence_length_train``, ...); like ours, they count frames,
and ``periodic_boundary_conditions`` says which axes wrap. Particle-type ids
are kept as they are (LagrangeBench: 0 fluid, 1 solid wall, 2 moving wall).

Optional ``material_property`` and ``step_context`` datasets, and a ``key``
attribute with the trajectory's name, ride along in each group; LagrangeBench
ignores them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydantic import Field

from gns_framework.contracts import Dataset, Params
from gns_framework.data.atomic import atomic_path, write_text_atomic
from gns_framework.data.consistency import checked
from gns_framework.data.lazy import TrajectorySequence
from gns_framework.data.metadata import DatasetMetadata, parse_metadata
from gns_framework.data.radius import particle_spacing
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError

OPTIONAL_FIELDS = ("material_property", "step_context")


class LagrangeBenchDataset(Dataset):
    """HDF5 trajectories as LagrangeBench (TGV, RPF, LDC, DAM) stores them; needs h5py."""

    name = "lagrangebench"
    writable = True

    class Params(Params):
        num_particle_types: int = Field(9, ge=1, description="particle-type ids must lie in [0, this)")

    def metadata(self) -> DatasetMetadata:
        raw = self._raw_metadata()
        write_every = raw.get("write_every", 1)
        if isinstance(raw.get("dt"), (int, float)) and isinstance(write_every, (int, float)):
            # LagrangeBench's dt is the solver step; frames are write_every steps apart.
            raw["dt"], raw["write_every"] = raw["dt"] * write_every, 1
        if "sequence_length" not in raw:
            raw["sequence_length"] = self._frames()
        return parse_metadata(raw, self.path / "metadata.json")

    def _raw_metadata(self) -> dict:
        file = self.path / "metadata.json"
        try:
            raw = json.loads(file.read_text())
        except FileNotFoundError:
            raise DatasetError(f"{file}: metadata file not found") from None
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{file}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
        if not isinstance(raw, dict):
            raise DatasetError(f"{file}: expected a JSON object, got {type(raw).__name__}")
        return raw

    def _frames(self) -> int:
        """Frames per trajectory, from the first trajectory of the first split on disk."""
        import h5py

        for split in self.splits():
            with h5py.File(self.path / f"{split}.h5", "r") as handle:
                for key in sorted(handle):
                    return int(handle[key]["position"].shape[0])
        raise DatasetError(f"{self.path}: no split file with a trajectory to take the sequence length from")

    def has_split(self, name: str) -> bool:
        return (self.path / f"{name}.h5").is_file()

    def split(self, name: str) -> Sequence[Trajectory]:
        import h5py

        file = self.path / f"{name}.h5"
        if not file.is_file():
            raise DatasetError(f"{file}: split file not found")
        metadata = self.metadata()
        # LagrangeBench splits may differ in length (one long training run, shorter test runs).
        length = self._raw_metadata().get(f"sequence_length_{name}")
        if length is not None:
            metadata = metadata.model_copy(update={"sequence_length": int(length)})
        try:
            with h5py.File(file, "r") as handle:
                keys = sorted(handle)
        except OSError as exc:
            raise DatasetError(f"{file}: not a readable HDF5 file (truncated or corrupt?): {exc}") from None

        def load(key: str) -> Trajectory:
            with h5py.File(file, "r") as handle:
                group = handle[key]
                if not isinstance(group, h5py.Group):
                    raise DatasetError(f"{file}: trajectory {key!r}: expected a group with position and particle_type")
                for required in ("position", "particle_type"):
                    if required not in group:
                        raise DatasetError(f"{file}: trajectory {key!r}: {required}: missing")
                optional = {f: group[f][()] for f in OPTIONAL_FIELDS if f in group}
                name_attr = group.attrs.get("key", key)
                trajectory = Trajectory(
                    group["position"][()],
                    group["particle_type"][()],
                    optional.get("material_property"),
                    optional.get("step_context"),
                    name_attr.decode() if isinstance(name_attr, bytes) else str(name_attr),
                )
            return checked(trajectory, metadata, str(file), self.params.num_particle_types)

        return TrajectorySequence(keys, load, str(file), metadata.dim)

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: dict[str, Sequence[Trajectory]]) -> None:
        import h5py

        path = Path(path)
        extras: dict = {"write_every": 1, "periodic_boundary_conditions": [False] * metadata.dim}
        for split, trajectories in splits.items():
            with atomic_path(path / f"{split}.h5", suffix=".h5") as tmp:
                with h5py.File(tmp, "w") as handle:
                    for index, traj in enumerate(trajectories):
                        group = handle.create_group(f"{index:05d}")
                        group.create_dataset("position", data=np.asarray(traj.position, dtype=np.float32))
                        group.create_dataset("particle_type", data=np.asarray(traj.particle_type, dtype=np.int64))
                        for name in OPTIONAL_FIELDS:
                            if getattr(traj, name) is not None:
                                group.create_dataset(name, data=np.asarray(getattr(traj, name), dtype=np.float32))
                        if traj.key:
                            group.attrs["key"] = traj.key
            if trajectories:
                extras[f"sequence_length_{split}"] = int(trajectories[0].num_steps)
                extras[f"num_trajs_{split}"] = len(trajectories)
        everything = [t for trajectories in splits.values() for t in trajectories]
        if everything:
            extras["num_particles_max"] = max(t.num_particles for t in everything)
            if everything[0].num_particles > 1:
                extras["dx"] = particle_spacing(everything[0].position[0])
        document = {**metadata.to_json_dict(), **extras}
        write_text_atomic(path / "metadata.json", json.dumps(document, indent=2) + "\n")
