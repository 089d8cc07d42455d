"""The arrays of a rollout as files hold them, checked field by field, and the rollout they make.

Shared by the two forms a rollout is written in: one ``.npz`` file (:mod:`.rollout_file`, whose
docstring lists the fields) and a folder of shards (:mod:`.sharded_rollout`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data.metadata import DatasetMetadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import DatasetError, located

OPTIONAL_FIELDS = ("material_property", "bounds", "walls")


def validated_fields(src: str, fields: dict[str, np.ndarray | None], metadata: DatasetMetadata) -> dict[str, Any]:
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


def rollout_from_fields(src: str, fields: dict[str, np.ndarray | None], metadata: DatasetMetadata, key: str) -> Rollout:
    """The rollout of a file's arrays (named as in the table above; the optional ones may be None), checked as a
    rollout file's are: DatasetError naming ``src`` and the field at fault."""
    arrays = validated_fields(src, fields, metadata)
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
