"""LagrangeBench's layout (Toshev et al. 2023): ``<split>.h5`` with one group per trajectory, plus ``metadata.json``.

Each group (``00000``, ``00001``, ...) holds ``position`` (T, N, d) and
``particle_type`` (N,). LagrangeBench's metadata differs from DeepMind's, and is
read as LagrangeBench defines it:

* ``dt`` is the solver's time step and frames are ``write_every`` steps apart, so
  the frame interval gns-framework uses is ``dt * write_every``; the solver step is
  kept as ``solver_dt`` (with ``write_every``) and written back as ``dt``.
* Sequence lengths are per split, ``sequence_length_<split>`` = T - 1 (steps
  between frames, as in DeepMind's files), with ``num_trajs_<split>``;
  LagrangeBench writes them for train and test only. Where the metadata gives no
  length for a split, each trajectory's length is taken from the file.
* ``periodic_boundary_conditions`` holds three entries whatever ``dim`` is; the
  first ``dim`` say which axes wrap.
* ``dx``, ``solver``, ``case`` and every other key gns-framework does not use are
  kept as they are when converting.

Particle-type ids are kept as they are (LagrangeBench: 0 fluid, 1 solid wall,
2 moving wall). A trajectory named by a number is stored in the group of that
number. Optional ``material_property`` and ``step_context`` datasets, and a
``key`` attribute with a trajectory name that is not its group's, ride along in
each group; LagrangeBench ignores them.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from gns_framework.api import (
    INFLATE_RATIO_ABOVE,
    MAX_INFLATE_RATIO,
    DatasetError,
    DatasetMetadata,
    GnsError,
    LimitError,
    Trajectory,
    TrajectorySequence,
    atomic_path,
    check_memory,
    checked,
    parse_metadata,
    particle_spacing,
    read_metadata_json,
    write_text_atomic,
)
from gns_framework.contracts import Dataset

from ._formats.numbering import trajectory_numbers

OPTIONAL_FIELDS = ("material_property", "step_context")
PER_SPLIT_KEYS = ("sequence_length_", "num_trajs_")
"""Prefixes of the metadata keys that describe the split files; a writer states them afresh."""


class LagrangeBenchDataset(Dataset):
    """HDF5 trajectories as LagrangeBench (TGV, RPF, LDC, DAM) stores them; needs h5py."""

    name = "lagrangebench"
    writable = True
    split_suffix = ".h5"

    def metadata(self) -> DatasetMetadata:
        raw = self._raw_metadata()
        write_every = raw.get("write_every")
        if isinstance(raw.get("dt"), (int, float)) and isinstance(write_every, (int, float)):
            raw["solver_dt"], raw["dt"] = raw["dt"], raw["dt"] * write_every
        periodic, dim = raw.get("periodic_boundary_conditions"), raw.get("dim")
        if isinstance(periodic, list) and isinstance(dim, int) and len(periodic) > dim:
            raw["periodic_boundary_conditions"] = periodic[:dim]
        # gns-framework's sequence_length counts the frames of the training trajectories.
        steps = raw.get("sequence_length_train")
        raw["sequence_length"] = steps + 1 if isinstance(steps, int) else self._frames()
        return parse_metadata(raw, self.path / "metadata.json")

    def _raw_metadata(self) -> dict:
        return read_metadata_json(self.path / "metadata.json")

    def _frames(self) -> int:
        """Frames of the first trajectory of the first split on disk (train when there is one)."""
        import h5py

        for split in self.splits():
            file = self.path / f"{split}.h5"
            with damaged_hdf5(file, "sequence length"), h5py.File(file, "r") as handle:
                for key in sorted(handle):
                    return int(handle[key]["position"].shape[0])
        raise DatasetError(f"{self.path}: no split file with a trajectory to take the sequence length from")

    def split(self, name: str) -> Sequence[Trajectory]:
        import h5py

        file = self.split_file(name)
        metadata = self.metadata()
        steps = self._raw_metadata().get(f"sequence_length_{name}")
        if steps is not None and not (isinstance(steps, int) and steps >= 1):
            raise DatasetError(
                f"{self.path / 'metadata.json'}: sequence_length_{name}: expected an integer >= 1, got {steps!r}"
            )
        frames = None if steps is None else steps + 1
        promise = f"sequence_length_{name} = {steps} (steps between frames, as LagrangeBench counts)"
        with damaged_hdf5(file, "its trajectories"), h5py.File(file, "r") as handle:
            keys = sorted(handle)

        def load(key: str) -> Trajectory:
            with damaged_hdf5(file, f"trajectory {key!r}"), h5py.File(file, "r") as handle:
                group = handle[key]
                if not isinstance(group, h5py.Group):
                    raise DatasetError(f"{file}: trajectory {key!r}: expected a group with position and particle_type")
                for required in ("position", "particle_type"):
                    if required not in group:
                        raise DatasetError(f"{file}: trajectory {key!r}: {required}: missing")
                read = lambda field: read_bounded(group, field, f"{file}: trajectory {key!r}")  # noqa: E731
                optional = {f: read(f) for f in OPTIONAL_FIELDS if f in group}
                name_attr = group.attrs.get("key", key)
                trajectory = Trajectory(
                    read("position"),
                    read("particle_type"),
                    optional.get("material_property"),
                    optional.get("step_context"),
                    name_attr.decode() if isinstance(name_attr, bytes) else str(name_attr),
                )
            return checked(trajectory, str(file), metadata.dim, frames, promise)

        return TrajectorySequence(keys, load, str(file), metadata.domain_check(), keep=self.keep_trajectories)

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        import h5py

        path = Path(path)
        document = lagrangebench_metadata(path, metadata, splits)
        for split, trajectories in splits.items():
            with atomic_path(path / f"{split}.h5", suffix=".h5") as tmp, h5py.File(tmp, "w") as handle:
                for number, traj in zip(trajectory_numbers(trajectories), trajectories, strict=True):
                    group_name = f"{number:05d}"
                    group = handle.create_group(group_name)
                    group.create_dataset("position", data=np.asarray(traj.position, dtype=np.float32))
                    group.create_dataset("particle_type", data=np.asarray(traj.particle_type, dtype=np.int64))
                    for name in OPTIONAL_FIELDS:
                        if getattr(traj, name) is not None:
                            group.create_dataset(name, data=np.asarray(getattr(traj, name), dtype=np.float32))
                    if traj.key and traj.key != group_name:
                        group.attrs["key"] = traj.key
        write_text_atomic(path / "metadata.json", json.dumps(document, indent=2) + "\n")


@contextlib.contextmanager
def damaged_hdf5(file: Path, reading: str) -> Iterator[None]:
    """HDF5's errors on a damaged file (h5py raises OSError, RuntimeError, KeyError, ValueError or TypeError from
    deep in the library) as one DatasetError naming the file and what was being read."""
    try:
        yield
    except GnsError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, AttributeError, IndexError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DatasetError(
            f"{file}: not a readable HDF5 file (truncated or corrupt?) reading {reading}: {first}"
        ) from None


def read_bounded(group, field: str, where: str) -> np.ndarray:
    """Dataset ``field`` of ``group``, its declared size checked against the limits before h5py allocates it.

    An HDF5 dataset declares its shape; a chunked one may declare far more than the
    file stores (unwritten chunks read as the fill value), so a few KB can ask for TB.
    """
    import h5py

    dataset = group[field]
    if not isinstance(dataset, h5py.Dataset):
        raise DatasetError(f"{where}: {field}: expected an array, found a {type(dataset).__name__}")
    nbytes = math.prod(dataset.shape or ()) * dataset.dtype.itemsize
    stored = max(1, dataset.id.get_storage_size())
    if nbytes > INFLATE_RATIO_ABOVE and nbytes > MAX_INFLATE_RATIO * stored:
        raise LimitError(
            f"{where}: {field}: declares {nbytes:,} bytes {dataset.shape} but stores {stored:,} "
            f"({nbytes / stored:,.0f}x, more than the {MAX_INFLATE_RATIO}x any particle data compresses)"
        )
    check_memory(where, nbytes, f"{field} {dataset.shape}")
    return dataset[()]


def lagrangebench_metadata(path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> dict:
    """``metadata`` in LagrangeBench's terms, with the lengths and counts of ``splits`` (to be written under ``path``).

    Every key of ``metadata`` is kept; with ``write_every``, ``dt`` becomes the solver
    step again (``solver_dt`` when it still gives the frame interval, else ``dt / write_every``).
    """
    document = {k: v for k, v in metadata.to_json_dict().items() if not k.startswith(PER_SPLIT_KEYS)}
    del document["sequence_length"]
    solver_dt = document.pop("solver_dt", None)
    write_every = document.get("write_every")
    if isinstance(write_every, (int, float)) and write_every > 0:
        # The reader made dt as this very product (exact to an ulp); a frame stride since changes it by a whole factor.
        consistent = isinstance(solver_dt, (int, float)) and math.isclose(
            solver_dt * write_every, metadata.dt, rel_tol=4 * sys.float_info.epsilon
        )
        document["dt"] = solver_dt if consistent else metadata.dt / write_every
    document["periodic_boundary_conditions"] = metadata.periodic_boundary_conditions or [False] * metadata.dim
    for split, trajectories in splits.items():
        lengths = sorted({traj.num_steps for traj in trajectories})
        if len(lengths) > 1:
            raise DatasetError(
                f"{path / split}.h5: trajectories of {lengths} frames, but LagrangeBench's layout holds one "
                "sequence length per split; write this dataset as safe"
            )
        if lengths:
            document[f"sequence_length_{split}"] = lengths[0] - 1
            document[f"num_trajs_{split}"] = len(trajectories)
    everything = [t for trajectories in splits.values() for t in trajectories]
    if everything:
        document["num_particles_max"] = max(
            document.get("num_particles_max", 0), *(t.num_particles for t in everything)
        )
        if "dx" not in document and everything[0].num_particles > 1:
            document["dx"] = particle_spacing(everything[0].position[0])
    return document
