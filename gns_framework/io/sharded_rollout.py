"""A rollout written in pieces, one per process, and read back as one rollout.

A scene rolled out over P processes (``gns rollout --partitions P``) is never whole in any one of
them: each owns the particles of its piece, and which particles those are changes as they move.
So every process writes its own shard, an HDF5 file, as the rollout goes, and the team's first
process writes the manifest once every shard is complete::

    <split>_<index>.rollout/
        rollout.json        the manifest: particles N, steps S, input frames C, the shards, the
                            dataset's metadata, the trajectory's key, bounds and walls
        shard-00000.h5 ...  one per process

A shard holds, by global particle id (0 .. N-1, the dataset's order):

=============================  ============  ===============================================
dataset                        shape         meaning
=============================  ============  ===============================================
``initial/ids``                (n0,) int64   the particles the process owned at the start
``initial/position``           (C, n0, d)    their C input frames (float32, length units)
``initial/particle_type``      (n0,) int64   their particle types
``initial/material_property``  (n0, P)       optional: their material properties
``initial/predicted``          (n0,) bool    whether the model predicts them (not kinematic)
``frames/offsets``             (S + 1,)      rows ``offsets[s]:offsets[s + 1]`` are step s
``frames/ids``                 (R,) int64    each row's particle
``frames/predicted``           (R, d)        its predicted position (float32)
``frames/truth``               (R, d)        its true position (float32)
``guard/...``                  (V,) ...      what the rollout guard found on its particles
=============================  ============  ===============================================

:func:`load_sharded_rollout` (and :func:`~.rollout_file.load_rollout`, which opens both forms)
puts the frames together, each particle exactly once per step, and checks everything a rollout
file's reader checks; a missing or incomplete shard is an error naming it. The shards of every
process must reach one folder: on several hosts, ``--out`` on a file system they share.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ..data.atomic import write_text_atomic
from ..data.metadata import DatasetMetadata, parse_metadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import DatasetError, located
from ..model.rollout_guard import GuardViolation, merged_violations
from .rollout_fields import rollout_from_fields

FORMAT = "gns-sharded-rollout"
VERSION = 1
MANIFEST = "rollout.json"
SUFFIX = ".rollout"
CHUNK_ROWS = 65_536
"""Most rows per HDF5 chunk of a shard's frames: about 0.5 MB of positions in 2D, 0.8 MB in 3D."""


def shard_name(rank: int) -> str:
    return f"shard-{rank:05d}.h5"


def is_sharded_rollout(path: str | Path) -> bool:
    """Whether ``path`` is a folder with a sharded rollout's manifest."""
    return (Path(path) / MANIFEST).is_file()


class RolloutShard:
    """This process's shard of a sharded rollout, written as the rollout goes.

    Call :meth:`start` once with the particles the process owns at the start, :meth:`frame` once per
    step with those it owns then, and :meth:`finish` at the end; :meth:`abandon` removes the file
    (a rollout that stopped writes nothing).
    """

    def __init__(self, folder: str | Path, rank: int):
        self.path = Path(folder) / shard_name(rank)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = h5py.File(self.path, "w")
        self._offsets = [0]

    def start(
        self,
        ids: np.ndarray,
        position: np.ndarray,
        particle_type: np.ndarray,
        material_property: np.ndarray | None,
        predicted: np.ndarray,
    ) -> None:
        """The owned particles' ``ids`` (n0,), input frames ``position`` (C, n0, d), types (n0,), material
        properties (n0, P) or None, and whether the model predicts each (n0,) bool."""
        initial = self._file.create_group("initial")
        initial["ids"] = np.asarray(ids, dtype=np.int64)
        initial["position"] = np.asarray(position, dtype=np.float32)
        initial["particle_type"] = np.asarray(particle_type, dtype=np.int64)
        initial["predicted"] = np.asarray(predicted, dtype=bool)
        if material_property is not None:
            initial["material_property"] = np.asarray(material_property, dtype=np.float32)
        dim = position.shape[-1]
        # About 16 steps of the process's particles a chunk (a small piece's file stays small), at most CHUNK_ROWS.
        rows = max(1024, min(CHUNK_ROWS, 16 * len(ids)))
        frames = self._file.create_group("frames")
        frames.create_dataset("ids", (0,), maxshape=(None,), dtype=np.int64, chunks=(rows,))
        for name in ("predicted", "truth"):
            frames.create_dataset(name, (0, dim), maxshape=(None, dim), dtype=np.float32, chunks=(rows, dim))

    def frame(self, ids: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> None:
        """The next step's rows: the particles owned now (n,), their predicted and true positions (n, d)."""
        frames, start = self._file["frames"], self._offsets[-1]
        stop = start + len(ids)
        for name, values in (("ids", ids), ("predicted", predicted), ("truth", truth)):
            frames[name].resize(stop, axis=0)
            frames[name][start:stop] = values
        self._offsets.append(stop)

    def finish(self, violations: list[GuardViolation]) -> Path:
        """Close the shard with the step offsets and what the guard found on this process's particles."""
        self._file["frames"]["offsets"] = np.asarray(self._offsets, dtype=np.int64)
        guard = self._file.create_group("guard")
        guard["step"] = np.asarray([v.step for v in violations], dtype=np.int64)
        guard["escaped"] = np.asarray([v.escaped for v in violations], dtype=bool)
        guard["excess"] = np.asarray([v.excess for v in violations], dtype=np.float64)
        guard["cause"] = np.asarray([v.cause for v in violations], dtype=h5py.string_dtype())
        guard["counts"] = np.asarray([len(v.particles) for v in violations], dtype=np.int64)
        guard["particles"] = np.concatenate([v.particles for v in violations] or [np.zeros(0)]).astype(np.int64)
        self._file.close()
        return self.path

    def abandon(self) -> None:
        self._file.close()
        self.path.unlink(missing_ok=True)


def write_manifest(
    folder: str | Path,
    trajectory: Trajectory,
    steps: int,
    history: int,
    processes: int,
    metadata: DatasetMetadata,
) -> Path:
    """The manifest of the shards of ``processes`` processes in ``folder``: a rollout of ``steps`` frames
    after the first ``history`` of ``trajectory``. Written last, so a folder without it is no rollout."""
    document = {
        "format": FORMAT,
        "version": VERSION,
        "key": trajectory.key,
        "particles": trajectory.num_particles,
        "steps": steps,
        "history": history,
        "dim": trajectory.dim,
        "shards": [shard_name(rank) for rank in range(processes)],
        "bounds": None if trajectory.bounds is None else np.asarray(trajectory.bounds).tolist(),
        "walls": None if trajectory.walls is None else np.asarray(trajectory.walls).tolist(),
        "metadata": metadata.to_json_dict(),
    }
    path = Path(folder) / MANIFEST
    write_text_atomic(path, json.dumps(document, indent=2) + "\n")
    return path


def load_sharded_rollout(folder: str | Path) -> Rollout:
    """The rollout in ``folder``, every frame put together from the shards; DatasetError naming the file and
    field at fault (a shard missing or incomplete, a particle missing or twice in a step, a wrong shape)."""
    folder = Path(folder)
    manifest = _manifest(folder)
    particles, steps, history, dim = (manifest[k] for k in ("particles", "steps", "history", "dim"))
    initial = np.full((history, particles, dim), np.nan, dtype=np.float32)
    particle_type = np.full(particles, -1, dtype=np.int64)
    predicted_particles = np.zeros(particles, dtype=bool)
    material_property: np.ndarray | None = None
    predicted = np.full((steps, particles, dim), np.nan, dtype=np.float32)
    truth = np.full((steps, particles, dim), np.nan, dtype=np.float32)
    seen_initial = np.zeros(particles, dtype=np.int64)
    seen = np.zeros((steps, particles), dtype=np.uint8)
    violations: list[GuardViolation] = []
    for name in manifest["shards"]:
        path = folder / name
        if not path.is_file():
            raise DatasetError(f"{path}: shard missing (the manifest lists {len(manifest['shards'])} shards)")
        try:
            with h5py.File(path, "r") as shard:
                ids = _ids(shard, path, "initial/ids", particles)
                initial[:, ids] = _array(shard, path, "initial/position", (history, len(ids), dim))
                particle_type[ids] = _array(shard, path, "initial/particle_type", (len(ids),))
                predicted_particles[ids] = _array(shard, path, "initial/predicted", (len(ids),))
                stored = shard.get("initial/material_property")
                if stored is not None:
                    width = stored.shape[-1] if stored.ndim == 2 else -1
                    values = _array(shard, path, "initial/material_property", (len(ids), width))
                    if material_property is None:
                        material_property = np.full((particles, width), np.nan, dtype=np.float32)
                    if material_property.shape[1] != width:
                        raise DatasetError(
                            located(str(path), "initial/material_property", "has another width than other shards'")
                        )
                    material_property[ids] = values
                seen_initial[ids] += 1
                offsets = _array(shard, path, "frames/offsets", (steps + 1,))
                rows = int(offsets[-1])
                if offsets[0] != 0 or np.any(np.diff(offsets) < 0):
                    raise DatasetError(located(str(path), "frames/offsets", "expected 0 first and never decreasing"))
                frame_ids = _ids(shard, path, "frames/ids", particles, rows)
                step_of_row = np.repeat(np.arange(steps), np.diff(offsets))
                predicted[step_of_row, frame_ids] = _array(shard, path, "frames/predicted", (rows, dim))
                truth[step_of_row, frame_ids] = _array(shard, path, "frames/truth", (rows, dim))
                np.add.at(seen, (step_of_row, frame_ids), 1)
                violations += _violations(shard, path, history)
        except OSError as exc:
            raise DatasetError(f"{path}: not a readable HDF5 shard ({exc})") from None
    _every_particle_once(folder, seen_initial[None], "initial")
    _every_particle_once(folder, seen, "frames")
    fields = {
        "initial_positions": initial,
        "predicted_rollout": predicted,
        "ground_truth_rollout": truth,
        "particle_type": particle_type,
        "material_property": material_property,
        "bounds": manifest["bounds"],
        "walls": manifest["walls"],
    }
    rollout = rollout_from_fields(str(folder), fields, manifest["metadata"], folder.name.removesuffix(SUFFIX))
    return replace(
        rollout,
        predicted_particles=predicted_particles,
        guard_violations=tuple(merged_violations(violations)),
    )


def _manifest(folder: Path) -> dict[str, Any]:
    """The manifest, checked field by field."""
    path = folder / MANIFEST
    if not path.is_file():
        raise DatasetError(f"{path}: not found: {folder} is not a sharded rollout (or it did not finish)")
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise DatasetError(located(str(path), "format", f"expected {FORMAT!r}"))
    if document.get("version") != VERSION:
        raise DatasetError(located(str(path), "version", f"expected {VERSION}, got {document.get('version')!r}"))
    for field, low in (("particles", 1), ("steps", 1), ("history", 1), ("dim", 2)):
        value = document.get(field)
        if not isinstance(value, int) or isinstance(value, bool) or value < low or (field == "dim" and value > 3):
            raise DatasetError(located(str(path), field, f"expected an integer >= {low}, got {value!r}"))
    shards = document.get("shards")
    if (
        not isinstance(shards, list)
        or not shards
        or any(not isinstance(s, str) or Path(s).name != s or not s.endswith(".h5") for s in shards)
    ):
        raise DatasetError(located(str(path), "shards", "expected a list of shard file names in the folder"))
    if not isinstance(document.get("key"), str):
        raise DatasetError(located(str(path), "key", "expected the trajectory's key (a string)"))
    dim = document["dim"]
    for field, shape in (("bounds", (dim, 2)), ("walls", (2 * dim, 2))):
        value = document.get(field)
        if value is not None:
            array = np.asarray(value, dtype=np.float64) if _numbers(value) else None
            if array is None or array.shape != shape or not np.isfinite(array).all():
                raise DatasetError(located(str(path), field, f"expected null or {shape} finite numbers"))
            document[field] = array.astype(np.float32)
    if not isinstance(document.get("metadata"), dict):
        raise DatasetError(located(str(path), "metadata", "expected the dataset's metadata (a JSON object)"))
    document["metadata"] = parse_metadata(document["metadata"], f"{path}: metadata")
    if document["metadata"].dim != dim:
        raise DatasetError(located(str(path), "dim", f"{dim}, but the metadata says dim = {document['metadata'].dim}"))
    return document


def _numbers(value: Any) -> bool:
    """Whether ``value`` is a nested list of plain numbers (no strings, objects or booleans)."""
    if isinstance(value, list):
        return all(_numbers(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _array(shard: h5py.File, path: Path, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """Dataset ``name`` of the shard, which must have ``shape`` and hold numbers (or booleans)."""
    if name not in shard or not isinstance(shard[name], h5py.Dataset):
        raise DatasetError(located(str(path), name, "missing"))
    values = shard[name][()]
    if values.shape != shape or not (np.issubdtype(values.dtype, np.number) or values.dtype == bool):
        raise DatasetError(located(str(path), name, f"expected {shape} numbers, got {values.dtype} {values.shape}"))
    return values


def _ids(shard: h5py.File, path: Path, name: str, particles: int, rows: int | None = None) -> np.ndarray:
    """Particle ids (each in 0 .. particles - 1); ``rows`` of them where given."""
    if name not in shard:
        raise DatasetError(located(str(path), name, "missing"))
    ids = _array(shard, path, name, (shard[name].shape[0] if rows is None else rows,))
    if not np.issubdtype(ids.dtype, np.integer) or (len(ids) and (ids.min() < 0 or ids.max() >= particles)):
        raise DatasetError(located(str(path), name, f"expected particle ids in 0 .. {particles - 1}"))
    return ids


def _violations(shard: h5py.File, path: Path, history: int) -> list[GuardViolation]:
    """What the guard found on this shard's particles."""
    if "guard" not in shard:
        raise DatasetError(located(str(path), "guard", "missing: the shard was not finished"))
    guard = shard["guard"]
    counts = guard["counts"][()]
    particles = np.split(guard["particles"][()], np.cumsum(counts)[:-1]) if len(counts) else []
    return [
        GuardViolation(int(step), int(step) + history, numbers, cause.decode(), bool(escaped), float(excess))
        for step, numbers, cause, escaped, excess in zip(
            guard["step"][()], particles, guard["cause"][()], guard["escaped"][()], guard["excess"][()], strict=True
        )
    ]


def _every_particle_once(folder: Path, seen: np.ndarray, group: str) -> None:
    """Refuse a rollout in which a particle is missing from a step, or stands in it twice."""
    wrong = np.argwhere(seen != 1)
    if len(wrong):
        step, particle = (int(i) for i in wrong[0])
        times = int(seen[step, particle])
        where = "the input frames" if group == "initial" else f"step {step}"
        raise DatasetError(
            f"{folder}: {group}: particle {particle} is in {times} shards for {where} (expected exactly 1); "
            f"{len(wrong)} such places in all"
        )
