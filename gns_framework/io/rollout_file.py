"""The rollout file: one predicted trajectory beside its ground truth, pickle-free.

A rollout file is an ``.npz`` holding, time-major like the datasets:

========================  ==========  =============================================
field                     shape       meaning
========================  ==========  =============================================
``initial_positions``     (C, N, d)   the C input frames the rollout starts from
``predicted_rollout``     (S, N, d)   predicted positions of the S following frames
``ground_truth_rollout``  (S, N, d)   true positions of the same frames
``particle_type``         (N,)        int64 particle-type ids
``material_property``     (N, P)      optional per-particle material properties
``metadata_json``         ()          str: the dataset's ``metadata.json``
========================  ==========  =============================================

Positions are float32 in the dataset's length unit; frames are ``metadata.dt``
seconds apart. Predicted positions may be non-finite (a diverged model is a
result to report, not a malformed file); every other array must be finite.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.atomic import atomic_path
from ..data.metadata import DatasetMetadata, parse_metadata
from ..errors import DatasetError, RolloutDiverged, located

if TYPE_CHECKING:
    from ..model.rollout import RolloutResult

REQUIRED_FIELDS = ("initial_positions", "predicted_rollout", "ground_truth_rollout", "particle_type", "metadata_json")
OPTIONAL_FIELDS = ("material_property",)


@dataclass(frozen=True)
class Rollout:
    """A validated rollout file in memory (shapes as in the module docstring)."""

    initial_positions: np.ndarray
    predicted_rollout: np.ndarray
    ground_truth_rollout: np.ndarray
    particle_type: np.ndarray
    metadata: DatasetMetadata
    material_property: np.ndarray | None = None
    source: str = "<memory>"

    @property
    def num_steps(self) -> int:
        """S, the number of rolled-out frames."""
        return int(self.predicted_rollout.shape[0])

    @property
    def num_particles(self) -> int:
        return int(self.particle_type.shape[0])

    @property
    def dim(self) -> int:
        return int(self.initial_positions.shape[2])

    def predicted_trajectory(self) -> np.ndarray:
        """(C + S, N, d): input frames followed by the prediction."""
        return np.concatenate([self.initial_positions, self.predicted_rollout])

    def ground_truth_trajectory(self) -> np.ndarray:
        """(C + S, N, d): input frames followed by the ground truth."""
        return np.concatenate([self.initial_positions, self.ground_truth_rollout])


def validate_rollout(rollout: Rollout) -> Rollout:
    """Check shapes, dtypes and values; return a copy with canonical dtypes.

    Raises DatasetError naming the source file and the field at fault.
    """
    src = rollout.source
    initial = np.asarray(rollout.initial_positions)
    if initial.ndim != 3 or initial.shape[2] not in (2, 3) or initial.shape[0] < 1:
        raise DatasetError(
            located(src, "initial_positions", f"expected shape (C, N, d) with d = 2 or 3, got {initial.shape}")
        )
    _, n, d = initial.shape
    if d != rollout.metadata.dim:
        raise DatasetError(
            located(src, "initial_positions", f"has d = {d} but metadata says dim = {rollout.metadata.dim}")
        )
    _require_finite(src, "initial_positions", initial)
    truth = np.asarray(rollout.ground_truth_rollout)
    if truth.ndim != 3 or truth.shape[1:] != (n, d) or truth.shape[0] < 1:
        raise DatasetError(located(src, "ground_truth_rollout", f"expected shape (S, {n}, {d}), got {truth.shape}"))
    _require_finite(src, "ground_truth_rollout", truth)
    predicted = np.asarray(rollout.predicted_rollout)
    if not np.issubdtype(predicted.dtype, np.number):
        raise DatasetError(located(src, "predicted_rollout", f"expected numbers, got {predicted.dtype}"))
    if predicted.shape != truth.shape:
        raise DatasetError(
            located(
                src,
                "predicted_rollout",
                f"expected shape {truth.shape} like ground_truth_rollout, got {predicted.shape}",
            )
        )
    ptype = np.asarray(rollout.particle_type)
    if ptype.shape != (n,):
        raise DatasetError(located(src, "particle_type", f"expected shape ({n},), got {ptype.shape}"))
    if not np.issubdtype(ptype.dtype, np.integer):
        raise DatasetError(located(src, "particle_type", f"expected integer ids, got {ptype.dtype}"))
    if ptype.min() < 0:
        raise DatasetError(located(src, "particle_type", f"ids must be >= 0, got {ptype.min()}"))
    prop = rollout.material_property
    if prop is not None:
        prop = np.asarray(prop, dtype=np.float32)
        if prop.ndim == 1:
            prop = prop[:, None]
        if prop.ndim != 2 or prop.shape[0] != n:
            raise DatasetError(located(src, "material_property", f"expected shape ({n}, P), got {prop.shape}"))
        _require_finite(src, "material_property", prop)
    return Rollout(
        initial_positions=initial.astype(np.float32, copy=False),
        predicted_rollout=predicted.astype(np.float32, copy=False),
        ground_truth_rollout=truth.astype(np.float32, copy=False),
        particle_type=ptype.astype(np.int64, copy=False),
        metadata=rollout.metadata,
        material_property=prop,
        source=src,
    )


def _require_finite(source: str, field: str, values: np.ndarray) -> None:
    if not np.issubdtype(values.dtype, np.number):
        raise DatasetError(located(source, field, f"expected numbers, got {values.dtype}"))
    if not np.isfinite(values).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
        raise DatasetError(located(source, field, f"non-finite value at index {bad}"))


def save_rollout(path: str | Path, rollout: Rollout) -> Path:
    """Validate ``rollout`` and write it to ``path`` (an ``.npz``, compressed)."""
    path = Path(path)
    rollout = validate_rollout(rollout)
    arrays = {
        "initial_positions": rollout.initial_positions,
        "predicted_rollout": rollout.predicted_rollout,
        "ground_truth_rollout": rollout.ground_truth_rollout,
        "particle_type": rollout.particle_type,
        "metadata_json": np.array(json.dumps(rollout.metadata.to_json_dict())),
    }
    if rollout.material_property is not None:
        arrays["material_property"] = rollout.material_property
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)
    return path


def load_rollout(path: str | Path) -> Rollout:
    """Read and validate a rollout file; never unpickles (``allow_pickle=False``)."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise DatasetError(f"{src}: rollout file not found")
    # np.load would try to unpickle anything that is not an archive: check first.
    if not zipfile.is_zipfile(path):
        raise DatasetError(f"{src}: not a readable .npz rollout file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            fields = {name: archive[name] for name in archive.files}
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise DatasetError(f"{src}: not a readable .npz rollout file ({exc})") from None
    except ValueError as exc:
        # np.load refuses object arrays without allow_pickle: a pickled file.
        raise DatasetError(f"{src}: holds pickled objects, which rollout files never contain ({exc})") from None
    missing = [name for name in REQUIRED_FIELDS if name not in fields]
    if missing:
        raise DatasetError(f"{src}: missing field(s) {', '.join(missing)}; found {', '.join(sorted(fields)) or 'none'}")
    unknown = sorted(set(fields) - set(REQUIRED_FIELDS) - set(OPTIONAL_FIELDS))
    if unknown:
        raise DatasetError(f"{src}: unknown field(s) {', '.join(unknown)}")
    raw_metadata = fields["metadata_json"]
    if raw_metadata.shape != () or raw_metadata.dtype.kind != "U":
        raise DatasetError(
            located(src, "metadata_json", f"expected a 0-d string array, got {raw_metadata.dtype} {raw_metadata.shape}")
        )
    try:
        metadata_dict = json.loads(str(raw_metadata))
    except json.JSONDecodeError as exc:
        raise DatasetError(located(src, "metadata_json", f"not valid JSON ({exc.msg})")) from None
    if not isinstance(metadata_dict, dict):
        raise DatasetError(located(src, "metadata_json", f"expected a JSON object, got {type(metadata_dict).__name__}"))
    metadata = parse_metadata(metadata_dict, f"{src}: metadata_json")
    return validate_rollout(
        Rollout(
            initial_positions=fields["initial_positions"],
            predicted_rollout=fields["predicted_rollout"],
            ground_truth_rollout=fields["ground_truth_rollout"],
            particle_type=fields["particle_type"],
            metadata=metadata,
            material_property=fields.get("material_property"),
            source=src,
        )
    )


def write_rollout(
    path: str | Path, result: "RolloutResult", metadata: DatasetMetadata, allow_non_finite: bool = False
) -> Path:
    """Save a rollout with its ground truth, atomically; an existing file is replaced only on success.

    Non-finite predictions (from a rollout made without a guard) are refused unless
    ``allow_non_finite`` says a diverged rollout is to be kept as a result.
    """
    finite = np.isfinite(result.predicted).all(axis=(1, 2))
    if not allow_non_finite and not finite.all():
        step = int(np.argmin(finite))
        particles = np.flatnonzero(~np.isfinite(result.predicted[step]).all(axis=-1))
        raise RolloutDiverged(
            f"{path}: predicted_rollout: non-finite positions from step {step} on "
            f"(particles {particles[:5].tolist()}{', ...' if len(particles) > 5 else ''}, {len(particles)} in all); "
            "not written (pass allow_non_finite=True to keep a diverged rollout)",
            trajectory=result.trajectory.key, step=step, particles=particles.tolist(), cause="non-finite positions",
        )

    return save_rollout(
        path,
        Rollout(
            initial_positions=result.initial_positions.astype(np.float32),
            predicted_rollout=result.predicted.astype(np.float32),
            ground_truth_rollout=result.ground_truth.astype(np.float32),
            particle_type=result.trajectory.particle_type.astype(np.int64),
            metadata=metadata,
            material_property=result.trajectory.material_property,
        ),
    )
