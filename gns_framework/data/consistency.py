"""Checks of a loaded trajectory against its dataset's metadata, naming file, trajectory and field."""

from __future__ import annotations

from ..errors import DatasetError
from .metadata import DatasetMetadata
from .trajectory import Trajectory


def checked(trajectory: Trajectory, metadata: DatasetMetadata, source: str, num_particle_types: int) -> Trajectory:
    """``trajectory`` validated (shapes, dtypes, finite values, dimension, type ids in
    ``[0, num_particle_types)``) and holding the ``sequence_length`` frames the metadata promises."""
    valid = trajectory.validated(source, dim=metadata.dim, num_particle_types=num_particle_types)
    if valid.num_steps != metadata.sequence_length:
        raise DatasetError(
            f"{source}: trajectory {valid.key!r}: position: has {valid.num_steps} frames but metadata "
            f"promises sequence_length = {metadata.sequence_length}"
        )
    return valid
