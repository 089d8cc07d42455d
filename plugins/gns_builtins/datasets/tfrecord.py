"""DeepMind's layout (Learning to Simulate): ``<split>.tfrecord`` of SequenceExamples plus ``metadata.json``.

Each record is one trajectory::

    context        key                int64          trajectory number
                   particle_type      bytes          (N,) int64
    feature_lists  position           T x bytes      (N * d,) float32 per frame
                   step_context       T x bytes      (C,) float32 per frame, optional

DeepMind's ``metadata.json`` gives ``sequence_length`` = T - 1 (steps), where
gns-framework counts frames (T): the layout converts both ways. It is one length
for every split, so trajectories of other lengths are refused when writing. Read
and written without TensorFlow. Two optional context features carry what
DeepMind's files lack and its reader ignores: ``material_property`` ((N * P,)
float32 bytes) and ``trajectory_key`` (the trajectory's name, utf-8, when it is
not the decimal ``key``). A trajectory keeps its ``key`` number when converted:
trajectories whose names are all numbers are written under those numbers, others
are numbered in order.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from pydantic import Field

from gns_framework.api import (
    DatasetError,
    DatasetMetadata,
    Trajectory,
    TrajectorySequence,
    atomic_path,
    checked,
    load_metadata,
    write_text_atomic,
)
from gns_framework.contracts import ComponentParams, Dataset

from ._formats.numbering import trajectory_numbers
from ._formats.tfrecord_format import Feature, SequenceExample, read_records, write_records


class TfRecordDataset(Dataset):
    """The DeepMind TFRecord layout (WaterDrop, Sand, Goop, MultiMaterial, ...)."""

    name = "tfrecord"
    writable = True
    split_suffix = ".tfrecord"

    class Params(ComponentParams):
        verify_checksums: bool = Field(True, description="check every record's CRC-32C (slow without google-crc32c)")

    params: Params  # the validated Params above (the base class assigns it)

    def metadata(self) -> DatasetMetadata:
        stored = load_metadata(self.path)
        return stored.model_copy(update={"sequence_length": stored.sequence_length + 1})

    def split(self, name: str) -> Sequence[Trajectory]:
        file = self.split_file(name)
        metadata = self.metadata()
        records = list(read_records(file, verify=self.params.verify_checksums))

        def load(key: str) -> Trajectory:
            index = int(key)
            try:
                example = SequenceExample.parse(records[index])
            except (ValueError, UnicodeDecodeError) as exc:
                raise DatasetError(f"{file}: trajectory {index}: not a SequenceExample: {exc}") from None
            trajectory = _decode(example, metadata.dim, f"{file}: trajectory {index}")
            promise = f"sequence_length = {metadata.sequence_length - 1} (steps, as DeepMind counts)"
            return checked(trajectory, str(file), metadata.dim, metadata.sequence_length, promise)

        return TrajectorySequence(
            [str(i) for i in range(len(records))], load, str(file), metadata.domain_check(), keep=self.keep_trajectories
        )

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        path = Path(path)
        # Checked before any file is written, so a refused dataset leaves no partial copy.
        for split, trajectories in splits.items():
            for traj in trajectories:
                if traj.num_steps != metadata.sequence_length:
                    raise DatasetError(
                        f"{path / split}.tfrecord: trajectory {traj.key!r}: position: has {traj.num_steps} frames, "
                        f"but DeepMind's layout holds one sequence_length for every split and it is "
                        f"{metadata.sequence_length} frames; write this dataset as safe or lagrangebench"
                    )
        for split, trajectories in splits.items():
            numbers = trajectory_numbers(trajectories)
            records = [_encode(number, traj).serialize() for number, traj in zip(numbers, trajectories, strict=True)]
            with atomic_path(path / f"{split}.tfrecord") as tmp:
                write_records(tmp, records)
        document = {**metadata.to_json_dict(), "sequence_length": metadata.sequence_length - 1}
        write_text_atomic(path / "metadata.json", json.dumps(document, indent=2) + "\n")


def _single_bytes(feature: Feature, where: str) -> bytes:
    if feature.kind != "bytes" or len(feature.values) != 1:
        raise DatasetError(f"{where}: expected one bytes value, got {feature.kind} x {len(feature.values)}")
    return feature.values[0]


def _decode(example: SequenceExample, dim: int, where: str) -> Trajectory:
    for name, present in (("particle_type", example.context), ("position", example.feature_lists)):
        if name not in present:
            raise DatasetError(f"{where}: {name}: missing")
    particle_type = np.frombuffer(_single_bytes(example.context["particle_type"], f"{where}: particle_type"), "<i8")
    n = particle_type.shape[0]
    frames = [np.frombuffer(_single_bytes(f, f"{where}: position"), "<f4") for f in example.feature_lists["position"]]
    if not frames or any(frame.size != n * dim for frame in frames):
        sizes = sorted({frame.size for frame in frames})
        raise DatasetError(f"{where}: position: expected {n} x {dim} = {n * dim} floats per frame, got {sizes}")
    position = np.stack(frames).reshape(len(frames), n, dim)
    step_context = None
    if "step_context" in example.feature_lists:
        rows = example.feature_lists["step_context"]
        step_context = np.stack([np.frombuffer(_single_bytes(f, f"{where}: step_context"), "<f4") for f in rows])
    material_property = None
    if "material_property" in example.context:
        raw = _single_bytes(example.context["material_property"], f"{where}: material_property")
        values = np.frombuffer(raw, "<f4")
        if n == 0 or values.size % n:
            raise DatasetError(f"{where}: material_property: {values.size} floats do not split over {n} particles")
        material_property = values.reshape(n, -1)
    key = str(int(example.context["key"].values[0])) if "key" in example.context else ""
    if "trajectory_key" in example.context:
        key = _single_bytes(example.context["trajectory_key"], f"{where}: trajectory_key").decode()
    return Trajectory(position, particle_type, material_property, step_context, key)


def _encode(number: int, traj: Trajectory) -> SequenceExample:
    context = {
        "key": Feature("int64", np.array([number])),
        "particle_type": Feature("bytes", [np.asarray(traj.particle_type, "<i8").tobytes()]),
    }
    if traj.material_property is not None:
        context["material_property"] = Feature("bytes", [np.asarray(traj.material_property, "<f4").tobytes()])
    if traj.key and traj.key != str(number):
        context["trajectory_key"] = Feature("bytes", [traj.key.encode()])
    lists = {"position": [Feature("bytes", [np.asarray(frame, "<f4").tobytes()]) for frame in traj.position]}
    if traj.step_context is not None:
        lists["step_context"] = [Feature("bytes", [np.asarray(row, "<f4").tobytes()]) for row in traj.step_context]
    return SequenceExample(context, lists)
