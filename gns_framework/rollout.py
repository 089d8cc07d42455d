"""Autoregressive rollouts, guarded.

Every predicted frame passes a :class:`~gns_framework.rollout_guard.RolloutGuard`;
:func:`gns_framework.evaluation.rollout_file.write_rollout` saves a result with its
ground truth and refuses non-finite predictions unless told otherwise, so no NaN
reaches a file silently.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from tqdm import tqdm

from .allocator import keep_freed_memory
from .data.batch import window
from .data.trajectory import Trajectory
from .errors import DatasetError
from .precision import Precision, autocast
from .rollout_guard import GuardViolation, RolloutGuard
from .simulator import LearnedSimulator


@dataclass(frozen=True)
class RolloutResult:
    initial_positions: np.ndarray
    predicted: np.ndarray
    ground_truth: np.ndarray
    trajectory: Trajectory
    predicted_particles: np.ndarray
    guard_violations: tuple[GuardViolation, ...] = ()
    """What the guard clamped (empty when nothing was, or when it stops instead)."""

    @property
    def position_mse(self) -> float:
        """MSE over steps, predicted (non-kinematic) particles and dimensions."""
        moving = self.predicted_particles
        return float(((self.predicted - self.ground_truth)[:, moving] ** 2).mean())


@torch.inference_mode()
def rollout(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    steps: int | None = None,
    device: torch.device | str = "cpu",
    progress: bool = False,
    guard: RolloutGuard | None = None,
    precision: Precision = "float32",
) -> RolloutResult:
    """Predict ``steps`` frames from the first C of ``trajectory``.

    Kinematic particles follow their prescribed (ground-truth) positions; every other
    particle only ever sees its own predictions. ``guard`` checks every predicted
    frame (default: stop on non-finite positions, no domain check); it raises
    RolloutDiverged, or clamps and records the violations. ``precision`` picks the
    dtype of the model's products (:mod:`gns_framework.precision`); positions stay float32.
    """
    _check_simulates(simulator, trajectory)
    guard = guard if guard is not None else RolloutGuard(simulator.scene)
    keep_freed_memory()
    history = simulator.scene.history
    available = trajectory.num_steps - history
    steps = available if steps is None else min(steps, available)
    if steps < 1:
        raise ValueError(f"trajectory {trajectory.key!r} has {trajectory.num_steps} frames; rollout needs more than {history}")
    state = window(trajectory, 0, history, with_target=False).to(device)
    truth = torch.from_numpy(trajectory.position[history : history + steps]).to(device)
    kinematic = ~simulator.predicted_mask(state.particle_type)[:, None]
    sequence = state.position_sequence
    predicted = torch.empty_like(truth)
    context = None if trajectory.step_context is None else torch.from_numpy(trajectory.step_context).to(device)
    violations: list[GuardViolation] = []
    for step in tqdm(range(steps), desc=f"rollout {trajectory.key}", unit="step", disable=not progress):
        frame_context = None if context is None else context[history - 1 + step][None]
        current = replace(state, position_sequence=sequence, context=frame_context)
        with autocast(precision, device):
            next_position = simulator.predict_next_position(current, prescribed=truth[step])
        next_position = next_position.to(predicted.dtype)
        next_position, found = guard.check(step, next_position, sequence[:, -1], trajectory.key)
        violations += found
        predicted[step] = next_position
        sequence = torch.cat([sequence[:, 1:], next_position[:, None]], dim=1)
    return RolloutResult(
        initial_positions=trajectory.position[:history],
        predicted=predicted.cpu().numpy(),
        ground_truth=truth.cpu().numpy(),
        trajectory=trajectory,
        predicted_particles=(~kinematic[:, 0]).cpu().numpy(),
        guard_violations=tuple(violations),
    )


def _check_simulates(simulator: LearnedSimulator, trajectory: Trajectory) -> None:
    """Refuse a trajectory of another dimension or with particle types the model was not built for."""
    scene = simulator.scene
    where = f"trajectory {trajectory.key!r}"
    if trajectory.dim != scene.dim:
        raise DatasetError(f"{where}: position: has d = {trajectory.dim} but the model simulates dim = {scene.dim}")
    unknown = sorted(set(np.unique(trajectory.particle_type).tolist()) - set(scene.particle_types))
    if unknown:
        raise DatasetError(f"{where}: particle_type: ids {unknown} are not among the model's {list(scene.particle_types)}")
