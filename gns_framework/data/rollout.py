"""A rollout: a trajectory (the truth) beside the positions a simulator predicted for it.

One record serves every stage: :func:`gns_framework.model.rollout.rollout` returns
it, rollout files (:mod:`gns_framework.io.rollout_file`) hold it, the evaluation
scores it and the renderers draw it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .trajectory import Trajectory

if TYPE_CHECKING:
    from ..model.rollout_guard import GuardViolation
    from .metadata import DatasetMetadata


def _of_truth(name: str, doc: str) -> property:
    """A read-only attribute of the rollout that is its ground-truth trajectory's ``name``."""
    return property(lambda rollout: getattr(rollout.truth, name), doc=doc)


@dataclass(frozen=True)
class Rollout:
    """A predicted trajectory beside its ground truth.

    Positions are in the dataset's length unit L; frames are ``metadata.dt`` seconds apart.

    Attributes:
        truth: the true trajectory, its C input frames followed by the S rolled-out
            frames (T = C + S).
        predicted: (S, N, d) predicted positions of the S frames after the inputs; may be
            non-finite (a diverged model is a result to report).
        history: C, the input frames the rollout starts from.
        metadata: the dataset's metadata (bounds, dt, ...), or None where not known
            (a rollout straight from a model; a rollout file always has it).
        predicted_particles: (N,) bool, the particles the model predicts (not kinematic),
            or None where not known (a rollout read from a file).
        guard_violations: what the rollout guard clamped (empty when nothing was, or when
            it stops instead).
        source: the file it was read from ("<memory>" otherwise), named in messages.
    """

    truth: Trajectory
    predicted: np.ndarray
    history: int
    metadata: DatasetMetadata | None = None
    predicted_particles: np.ndarray | None = None
    guard_violations: tuple[GuardViolation, ...] = ()
    source: str = "<memory>"

    def __post_init__(self) -> None:
        # Every property slices the truth at ``history``: a mismatch would surface far from its cause.
        frames, particles, dim = self.truth.position.shape
        if not 1 <= self.history < frames:
            raise ValueError(
                f"{self.source}: history: expected 1 to {frames - 1} (of {frames} frames), got {self.history}"
            )
        expected = (frames - self.history, particles, dim)
        if np.shape(self.predicted) != expected:
            raise ValueError(f"{self.source}: predicted: expected shape {expected}, got {np.shape(self.predicted)}")

    @property
    def initial_positions(self) -> np.ndarray:
        """(C, N, d): the input frames the rollout starts from."""
        return self.truth.position[: self.history]

    @property
    def ground_truth(self) -> np.ndarray:
        """(S, N, d): true positions of the predicted frames."""
        return self.truth.position[self.history :]

    particle_type = _of_truth("particle_type", "(N,) int64 particle-type ids.")
    material_property = _of_truth("material_property", "(N, P) per-particle material properties, or None.")
    key = _of_truth("key", "The trajectory's name (file names and messages).")
    num_particles = _of_truth("num_particles", "N.")
    dim = _of_truth("dim", "d, the spatial dimensions.")

    @property
    def num_steps(self) -> int:
        """S, the number of rolled-out frames."""
        return int(self.predicted.shape[0])

    @property
    def position_mse(self) -> float:
        """MSE over steps, predicted (non-kinematic) particles and dimensions, L^2."""
        if self.predicted_particles is None:
            raise ValueError(f"{self.source}: which particles the model predicts is not recorded; no position MSE")
        moving = self.predicted_particles
        return float(((self.predicted - self.ground_truth)[:, moving] ** 2).mean())

    def predicted_trajectory(self) -> np.ndarray:
        """(C + S, N, d): input frames followed by the prediction."""
        return np.concatenate([self.initial_positions, self.predicted])

    def ground_truth_trajectory(self) -> np.ndarray:
        """(C + S, N, d): input frames followed by the ground truth."""
        return self.truth.position
