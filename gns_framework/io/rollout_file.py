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
``bounds``                (d, 2)      optional: the trajectory's own domain (else ``metadata.bounds``)
``walls``                 (2d, 2)     optional: each face's friction and no-slip flag
``metadata_json``         ()          str: the dataset's ``metadata.json``
========================  ==========  =============================================

Positions are float32 in the dataset's length unit; frames are ``metadata.dt``
seconds apart. Predicted positions may be non-finite (a diverged model is a
result to report, not a malformed file); every other array must be finite.

In memory a file is a :class:`~gns_framework.data.rollout.Rollout`: its true
trajectory is ``initial_positions`` followed by ``ground_truth_rollout``, named
after the file. A rollout over several processes is written as shards instead
(:mod:`.sharded_rollout`), which :func:`load_rollout` reads as one rollout too.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..data.atomic import atomic_path
from ..data.metadata import DatasetMetadata, parse_metadata
from ..data.rollout import Rollout
from ..errors import DatasetError, RolloutDiverged, located
from .rollout_fields import OPTIONAL_FIELDS, rollout_from_fields, validated_fields

REQUIRED_FIELDS = ("initial_positions", "predicted_rollout", "ground_truth_rollout", "particle_type", "metadata_json")


def save_rollout(path: str | Path, rollout: Rollout) -> Path:
    """Validate ``rollout`` (which must carry its metadata) and write it to ``path`` (an ``.npz``, compressed).

    Raises DatasetError naming ``rollout.source`` and the file field at fault.
    """
    path = Path(path)
    if rollout.metadata is None:
        raise ValueError(f"{rollout.source}: a rollout file needs the dataset's metadata; the rollout has none")
    fields = validated_fields(
        rollout.source,
        {
            "initial_positions": rollout.initial_positions,
            "predicted_rollout": rollout.predicted,
            "ground_truth_rollout": rollout.ground_truth,
            "particle_type": rollout.particle_type,
            "material_property": rollout.material_property,
            "bounds": rollout.truth.bounds,
            "walls": rollout.truth.walls,
        },
        rollout.metadata,
    )
    optional = {name: fields.pop(name) for name in OPTIONAL_FIELDS}
    arrays = {**fields, "metadata_json": np.array(json.dumps(rollout.metadata.to_json_dict()))}
    arrays.update({name: value for name, value in optional.items() if value is not None})
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)
    return path


def load_rollout(path: str | Path) -> Rollout:
    """Read and validate a rollout file, or a sharded rollout's folder (:mod:`.sharded_rollout`, written by a
    rollout over several processes) as one rollout; never unpickles (``allow_pickle=False``)."""
    path = Path(path)
    src = str(path)
    if path.is_dir():
        from .sharded_rollout import load_sharded_rollout

        return load_sharded_rollout(path)
    if not path.is_file():
        raise DatasetError(f"{src}: rollout file not found")
    # np.load would try to unpickle anything that is not an archive: check first.
    if not zipfile.is_zipfile(path):
        raise DatasetError(f"{src}: not a readable .npz rollout file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            fields = {name: archive[name] for name in archive.files}
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as exc:
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
    return rollout_from_fields(src, fields, metadata, path.stem)


def write_rollout(
    path: str | Path, rollout: Rollout, metadata: DatasetMetadata, allow_non_finite: bool = False
) -> Path:
    """Save a rollout with ``metadata``, atomically; an existing file is replaced only on success.

    Non-finite predictions (from a rollout made without a guard) are refused unless
    ``allow_non_finite`` says a diverged rollout is to be kept as a result.
    """
    finite = np.isfinite(rollout.predicted).all(axis=(1, 2))
    if not allow_non_finite and not finite.all():
        step = int(np.argmin(finite))
        particles = np.flatnonzero(~np.isfinite(rollout.predicted[step]).all(axis=-1))
        raise RolloutDiverged(
            f"{path}: predicted_rollout: non-finite positions from step {step} on "
            f"(particles {particles[:5].tolist()}{', ...' if len(particles) > 5 else ''}, {len(particles)} in all); "
            "not written (pass allow_non_finite=True to keep a diverged rollout)",
            trajectory=rollout.key,
            step=step,
            particles=particles.tolist(),
            cause="non-finite positions",
        )
    return save_rollout(path, replace(rollout, metadata=metadata))
