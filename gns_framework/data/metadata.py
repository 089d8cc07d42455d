"""Dataset metadata (``metadata.json``): domain, time step and normalisation statistics."""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Iterable
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ..errors import DatasetError
from .trajectory import DomainCheck, Trajectory

MAX_METADATA_BYTES = 16 * 2**20
"""Largest ``metadata.json`` read (it holds a few dozen numbers)."""


class DatasetMetadata(BaseModel):
    """The keys of a ``metadata.json`` shared by DeepMind, geoelements and our layouts.

    Lengths are in the dataset's units; ``vel_*`` and ``acc_*`` are statistics of the
    finite differences ``p[t+1] - p[t]`` and ``p[t+1] - 2 p[t] + p[t-1]`` (per frame,
    not per second), one value per spatial dimension.
    """

    model_config = ConfigDict(extra="allow")

    bounds: list[tuple[float, float]] = Field(description="(d, 2) lower and upper wall per dimension")
    sequence_length: int = Field(
        gt=1, description="frames per trajectory (T); DeepMind's, geoelements' and LagrangeBench's files count T - 1"
    )
    default_connectivity_radius: float = Field(gt=0)
    dim: int = Field(ge=2, le=3)
    dt: float = Field(gt=0, description="seconds between stored frames")
    vel_mean: list[float]
    vel_std: list[float]
    acc_mean: list[float]
    acc_std: list[float]
    context_mean: list[float] | None = None
    context_std: list[float] | None = None
    boundary_augment: float | None = Field(
        default=None, gt=0, description="clip limit of wall-distance features (geoelements); 1.0 when absent"
    )
    periodic_boundary_conditions: list[bool] | None = Field(
        default=None,
        description="per dimension, whether the domain wraps around (LagrangeBench's key); none when absent",
    )

    def domain_check(self) -> DomainCheck:
        """Where this dataset's particles may be: its bounds widened by two connectivity radii (a few spacings)."""
        return DomainCheck(np.asarray(self.bounds, dtype=np.float64), 2.0 * self.default_connectivity_radius)

    @model_validator(mode="after")
    def _dimensions_agree(self) -> DatasetMetadata:
        from ..limits import MAX_SEQUENCE_LENGTH

        if self.sequence_length > MAX_SEQUENCE_LENGTH:
            raise ValueError(
                f"sequence_length: {self.sequence_length:.6g} frames, more than the limit of {MAX_SEQUENCE_LENGTH:,}"
            )
        for field in ("default_connectivity_radius", "dt", "boundary_augment"):
            value = getattr(self, field)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"{field} must be finite, got {value}")
        for field in ("bounds", "vel_mean", "vel_std", "acc_mean", "acc_std", "context_mean", "context_std"):
            values = np.asarray(getattr(self, field) or [], dtype=np.float64)
            if not np.isfinite(values).all():
                raise ValueError(f"{field} must be finite, got {getattr(self, field)}")
        for field in ("bounds", "vel_mean", "vel_std", "acc_mean", "acc_std"):
            if len(getattr(self, field)) != self.dim:
                raise ValueError(f"{field} has {len(getattr(self, field))} entries but dim = {self.dim}")
        for field in ("vel_std", "acc_std", "context_std"):
            stds = getattr(self, field) or []
            if any(v < 0 or not math.isfinite(v) for v in stds):
                raise ValueError(f"{field} must be finite and >= 0, got {stds}")
        for lo, hi in self.bounds:
            if not lo < hi:
                raise ValueError(f"bounds must be (lower, upper) with lower < upper, got {(lo, hi)}")
        if self.periodic_boundary_conditions is not None and len(self.periodic_boundary_conditions) != self.dim:
            raise ValueError(
                f"periodic_boundary_conditions has {len(self.periodic_boundary_conditions)} entries but dim = "
                f"{self.dim}"
            )
        if (self.context_mean is None) != (self.context_std is None):
            raise ValueError("context_mean and context_std must be given together")
        if self.context_mean is not None and len(self.context_mean) != len(self.context_std or []):
            raise ValueError("context_mean and context_std must have the same length")
        return self

    @property
    def boundary_clamp_limit(self) -> float:
        return 1.0 if self.boundary_augment is None else float(self.boundary_augment)

    def to_json_dict(self) -> dict:
        return self.model_dump(mode="json", exclude_none=True)


def parse_metadata(raw: dict, source: str | Path, split: str | None = None) -> DatasetMetadata:
    """Validate a metadata mapping; ``source`` names the file in errors.

    geoelements also writes metadata nested per split (``{"train": {...}, "rollout": {...}}``);
    the entry for ``split`` (or ``train``) is taken then.
    """
    if "bounds" not in raw:
        nested = [k for k, v in raw.items() if isinstance(v, dict) and "bounds" in v]
        if nested:
            raw = raw[split if split in nested else ("train" if "train" in nested else nested[0])]
    try:
        return DatasetMetadata.model_validate(raw)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or '<root>'}: {err['msg']}" for err in exc.errors()
        )
        raise DatasetError(f"{source}: invalid metadata: {problems}") from None


def load_metadata(path: str | Path, split: str | None = None) -> DatasetMetadata:
    """Read and validate ``metadata.json`` (a file, or a folder holding one)."""
    path = Path(path)
    if path.is_dir():
        path = path / "metadata.json"
    return parse_metadata(read_metadata_json(path), path, split)


def read_metadata_json(path: Path) -> dict:
    """The JSON object of the metadata file ``path``, read with a size limit; one-line errors naming the file."""
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_METADATA_BYTES + 1)  # bounded: metadata.json -> /dev/zero must not fill memory
    except FileNotFoundError:
        raise DatasetError(f"{path}: metadata file not found") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read the metadata: {exc.strerror or exc}") from None
    if len(data) > MAX_METADATA_BYTES:
        raise DatasetError(f"{path}: more than {MAX_METADATA_BYTES // 2**20} MiB, too large for a metadata file")
    try:
        raw = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not UTF-8 text (byte {exc.start} is 0x{data[exc.start]:02x})") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except (ValueError, RecursionError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({type(exc).__name__})") from None
    if not isinstance(raw, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    return raw


def compute_statistics(
    trajectories: Iterable[Trajectory], kinematic_types: Collection[int], where: str = ""
) -> dict[str, list[float]]:
    """Mean and std of per-frame velocity and acceleration over non-kinematic particles.

    ``kinematic_types`` are the particle types whose material is kinematic (the
    registry's :meth:`~gns_framework.plugins.Registry.kinematic_types`, or a scene's):
    their prescribed motion is left out.

    Accumulates sums in float64 so long datasets do not lose precision; returns
    ``vel_mean``, ``vel_std``, ``acc_mean``, ``acc_std`` (and ``context_*`` when
    the trajectories carry a step context), each a list with one value per component.
    ``where`` (the dataset and split) starts the error when there is nothing to measure.
    """
    sums: dict[str, list] = {}

    def add(name: str, values: np.ndarray) -> None:
        values = values.reshape(-1, values.shape[-1]).astype(np.float64)
        acc = sums.setdefault(name, [0, np.zeros(values.shape[1]), np.zeros(values.shape[1])])
        acc[0] += values.shape[0]
        acc[1] += values.sum(0)
        acc[2] += (values**2).sum(0)

    counted = 0
    for traj in trajectories:
        counted += 1
        moving = ~np.isin(traj.particle_type, list(kinematic_types))
        pos = traj.position[:, moving].astype(np.float64)
        if pos.shape[0] >= 3 and pos.shape[1] > 0:
            vel = np.diff(pos, axis=0)
            add("vel", vel)
            add("acc", np.diff(vel, axis=0))
        if traj.step_context is not None:
            add("context", traj.step_context)
    if "vel" not in sums:
        holds = (
            "holds 0 trajectories"
            if not counted
            else f"none of its {counted} trajectories has 3 frames of non-kinematic particles"
        )
        raise DatasetError(f"{where + ': ' if where else ''}cannot compute statistics: {holds}")
    stats: dict[str, list[float]] = {}
    for name, (count, total, total_sq) in sums.items():
        mean = total / count
        var = np.maximum(total_sq / count - mean**2, 0.0)
        stats[f"{name}_mean"] = mean.tolist()
        stats[f"{name}_std"] = np.sqrt(var).tolist()
    return stats
