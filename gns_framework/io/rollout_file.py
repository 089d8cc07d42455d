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
from typing import Any

import numpy as np

from ..data.atomic import atomic_path
from ..data.metadata import DatasetMetadata, parse_metadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import DatasetError, RolloutDiverged, located

REQUIRED_FIELDS = ("initial_positions", "predicted_rollout", "ground_truth_rollout", "particle_type", "metadata_json")
OPTIONAL_FIELDS = ("material_property", "bounds", "walls")


def _validated_fields(src: str, fields: dict[str, np.ndarray | None], metadata: DatasetMetadata) -> dict[str, Any]:
    """Check a rollout file's arrays (every field but ``metadata_json``); return them with canonical dtypes.

    Each is an array; only those of ``OPTIONAL_FIELDS`` may be None.

    Raises DatasetError naming ``src`` (the file) and the field at fault.
    """
    initial = np.asarray(fields["initial_positions"])
    if initial.ndim != 3 or initial.shape[2] not in (2, 3) or initial.shape[0] < 1:
        raise DatasetError(
            located(src, "initial_positions", f"expected shape (C, N, d) with d = 2 or 3, got {initial.shape}")
        )
    _, n, d = initial.shape
    if d != metadata.dim:
        raise DatasetError(located(src, "initial_positions", f"has d = {d} but metadata says dim = {metadata.dim}"))
    _require_finite(src, "initial_positions", initial)
    truth = np.asarray(fields["ground_truth_rollout"])
    if truth.ndim != 3 or truth.shape[1:] != (n, d) or truth.shape[0] < 1:
        raise DatasetError(located(src, "ground_truth_rollout", f"expected shape (S, {n}, {d}), got {truth.shape}"))
    _require_finite(src, "ground_truth_rollout", truth)
    predicted = np.asarray(fields["predicted_rollout"])
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
    ptype = np.asarray(fields["particle_type"])
    if ptype.shape != (n,):
        raise DatasetError(located(src, "particle_type", f"expected shape ({n},), got {ptype.shape}"))
    if not np.issubdtype(ptype.dtype, np.integer):
        raise DatasetError(located(src, "particle_type", f"expected integer ids, got {ptype.dtype}"))
    if ptype.min() < 0:
        raise DatasetError(located(src, "particle_type", f"ids must be >= 0, got {ptype.min()}"))
    prop = fields.get("material_property")
    if prop is not None:
        prop = np.asarray(prop, dtype=np.float32)
        if prop.ndim == 1:
            prop = prop[:, None]
        if prop.ndim != 2 or prop.shape[0] != n:
            raise DatasetError(located(src, "material_property", f"expected shape ({n}, P), got {prop.shape}"))
        _require_finite(src, "material_property", prop)
    domain = {}
    for name, shape in (("bounds", (d, 2)), ("walls", (2 * d, 2))):
        value = fields.get(name)
        if value is not None:
            value = np.asarray(value)
            if value.shape != shape:
                raise DatasetError(located(src, name, f"expected shape {shape}, got {value.shape}"))
            _require_finite(src, name, value)
            value = value.astype(np.float32)
        domain[name] = value
    if domain["bounds"] is not None and not (domain["bounds"][:, 0] < domain["bounds"][:, 1]).all():
        raise DatasetError(
            located(src, "bounds", f"expected [lower, upper] with lower < upper, got {domain['bounds'].tolist()}")
        )
    return {
        **domain,
        "initial_positions": initial.astype(np.float32, copy=False),
        "predicted_rollout": predicted.astype(np.float32, copy=False),
        "ground_truth_rollout": truth.astype(np.float32, copy=False),
        "particle_type": ptype.astype(np.int64, copy=False),
        "material_property": prop,
    }


def _require_finite(source: str, field: str, values: np.ndarray) -> None:
    if not np.issubdtype(values.dtype, np.number):
        raise DatasetError(located(source, field, f"expected numbers, got {values.dtype}"))
    if not np.isfinite(values).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
        raise DatasetError(located(source, field, f"non-finite value at index {bad}"))


def save_rollout(path: str | Path, rollout: Rollout) -> Path:
    """Validate ``rollout`` (which must carry its metadata) and write it to ``path`` (an ``.npz``, compressed).

    Raises DatasetError naming ``rollout.source`` and the file field at fault.
    """
    path = Path(path)
    if rollout.metadata is None:
        raise ValueError(f"{rollout.source}: a rollout file needs the dataset's metadata; the rollout has none")
    fields = _validated_fields(
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


def rollout_from_fields(src: str, fields: dict[str, np.ndarray | None], metadata: DatasetMetadata, key: str) -> Rollout:
    """The rollout of a file's arrays (named as in the table above; the optional ones may be None), checked as a
    rollout file's are: DatasetError naming ``src`` and the field at fault."""
    arrays = _validated_fields(src, fields, metadata)
    initial = arrays["initial_positions"]
    truth = Trajectory(
        np.concatenate([initial, arrays["ground_truth_rollout"]]),
        arrays["particle_type"],
        arrays["material_property"],
        key=key,
        bounds=arrays["bounds"],
        walls=arrays["walls"],
    )
    return Rollout(truth, arrays["predicted_rollout"], len(initial), metadata, source=src)


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
