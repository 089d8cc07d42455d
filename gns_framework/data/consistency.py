"""Checks of a loaded trajectory against its dataset's metadata, naming file, trajectory and field."""

from __future__ import annotations

from ..errors import DatasetError
from .trajectory import Trajectory


def checked(trajectory: Trajectory, source: str, dim: int, frames: int | None, promise: str) -> Trajectory:
    """``trajectory`` validated (shapes, dtypes, finite values, ``dim``, type ids >= 0) and holding ``frames`` frames.

    ``promise`` quotes the metadata entry that gives ``frames`` in the file's own
    terms, for the error; ``frames`` None accepts any length. Which type ids a model
    handles is the installed materials' business, decided when the scene is built.
    """
    valid = trajectory.validated(source, dim=dim)
    if frames is not None and valid.num_steps != frames:
        raise DatasetError(
            f"{source}: trajectory {valid.key!r}: position: has {valid.num_steps} frames but metadata.json's "
            f"{promise} promises {frames}"
        )
    return valid
