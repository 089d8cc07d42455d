"""Many rollouts as one: B scenes stepped together, one graph and one model call per step.

Parametric studies, uncertainty and inverse problems roll one model out on many
cases. A learned step costs a fixed overhead (Python, dispatch, graph set-up) plus
work per particle; stepping the B scenes as one batch (their particles stacked,
examples never connected) pays the overhead once per step instead of B times. Each
scene's frames are its own: the same as :func:`~gns_framework.model.rollout.rollout`
of that scene alone up to float rounding (the graph and the sums are per particle;
only the matrix products see the stacked rows).

Every scene keeps its own walls (its ``bounds``, else the model's) for the guard,
and its kinematic particles follow their prescribed positions.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Sequence
from contextlib import AbstractContextManager, closing
from dataclasses import replace

import numpy as np
import torch

from ..data.batch import collate, window
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..runtime.precision import Precision
from .capacity_classes import CaptureClasses, padded, particle_capacity
from .captured_steps import CapturedSteps
from .learned_simulator import LearnedSimulator
from .rollout import check_simulates, sound_frames
from .rollout_guard import GuardViolation, RolloutGuard


def _per_particle_bounds(trajectories: Sequence[Trajectory]) -> torch.Tensor:
    """(N, d, 2) float64 walls of every stacked particle: its own scene's bounds."""
    per_particle = []
    for t in trajectories:
        assert t.bounds is not None  # the caller checks they all have their box
        per_particle.append(np.broadcast_to(np.asarray(t.bounds, np.float64), (t.num_particles, *np.shape(t.bounds))))
    return torch.from_numpy(np.concatenate(per_particle))


def _same_fields(simulator: LearnedSimulator, trajectories: Sequence[Trajectory]) -> list[Trajectory]:
    """The trajectories with the per-scene fields a batch stacks present in all or none.

    A scene without its own bounds is in the model's box; walls are kept only when the
    model takes them as inputs (then every scene needs them, as a single rollout does).
    """
    model = np.asarray(simulator.setup.bounds, dtype=np.float32)
    own_box = any(t.bounds is not None for t in trajectories)
    out = []
    for t in trajectories:
        bounds = (t.bounds if t.bounds is not None else model) if own_box else None
        walls = t.walls if simulator.setup.wall_conditions else None
        out.append(replace(t, bounds=bounds, walls=walls))
    return out


@torch.inference_mode()
def rollout_batch(
    simulator: LearnedSimulator,
    trajectories: Sequence[Trajectory],
    steps: int | None = None,
    device: torch.device | str = "cpu",
    guard: RolloutGuard | None = None,
    precision: Precision = "float32",
    capture: bool | CaptureClasses = False,
) -> list[Rollout]:
    """Predict ``steps`` frames of every trajectory from its first C, all scenes in one batch per step.

    ``steps`` defaults to the shortest trajectory's frames after the C inputs (every
    scene is rolled out as far as all of them go). Returns one :class:`Rollout` per
    trajectory, in order, each with the guard's violations of its own particles.
    ``capture`` replays one captured step for the whole batch, as :func:`~.rollout.rollout` does for one scene;
    :class:`~.capacity_classes.CaptureClasses` pads the batch to its capacity class and replays the class's capture
    (made by the first batch of the class: batches of similar size share one).
    """
    if not trajectories:
        return []
    for trajectory in trajectories:
        check_simulates(simulator, trajectory)
    history = simulator.setup.history
    available = min(t.num_steps for t in trajectories) - history
    steps = available if steps is None else min(steps, available)
    if steps < 1:
        raise ValueError(f"the shortest trajectory has {available + history} frames; rollout needs more than {history}")
    trajectories = _same_fields(simulator, trajectories)
    device = torch.device(device)
    guard = base_guard = guard if guard is not None else RolloutGuard(simulator.setup)
    if trajectories[0].bounds is not None:  # all of them have their own box, or none (the model's)
        guard = guard.with_bounds(_per_particle_bounds(trajectories))
    windows = [window(t, 0, history, with_target=False) for t in trajectories]
    state = collate(windows).to(device)
    counts = [t.num_particles for t in trajectories]
    ends = np.cumsum([0, *counts])
    truth = torch.from_numpy(np.concatenate([t.position[history : history + steps] for t in trajectories], axis=1))
    moving = simulator.predicted_mask(state.particle_type)
    kinematic = (~moving).nonzero()[:, 0]
    kinematic_truth = truth[:, kinematic.cpu()].to(device)
    step_guard = guard
    step_capture: CapturedSteps | bool = bool(capture)
    buffers: AbstractContextManager[None] = contextlib.nullcontext()
    if isinstance(capture, CaptureClasses):  # padded to its class, whose capture it replays
        capacity = particle_capacity(int(ends[-1]))
        state = padded(windows, capacity, capture.scenes).to(device)
        own = None if trajectories[0].bounds is None else _per_particle_bounds(trajectories)
        bounds = None if own is None else torch.cat([own, own[-1:].expand(capacity - len(own), *own.shape[1:])])
        kept = capture.of(simulator, base_guard, state, bounds, precision)
        step_guard, kinematic, step_capture = kept.guard, kept.every_row, kept.steps
        padding = torch.full((steps, capacity - len(moving), truth.shape[2]), float("nan"))
        kinematic_truth = torch.cat([truth, padding], dim=1).to(device)
        buffers = simulator.graph_builder.buffers(kept.key)
    predicted = torch.empty_like(truth)
    previous = torch.from_numpy(np.concatenate([t.position[history - 1] for t in trajectories]))
    violations: list[list[GuardViolation]] = [[] for _ in trajectories]
    label = ", ".join(t.key for t in trajectories[:3]) + (
        f", ... ({len(trajectories)} in all)" if len(trajectories) > 3 else ""
    )
    frames = sound_frames(
        simulator, step_guard, state, kinematic, kinematic_truth, steps, precision, capture=step_capture
    )
    with buffers, closing(frames):  # a guard's stop closes it: the builder checks its own builds again
        for step, next_position in frames:
            real = next_position[: len(moving)].cpu()
            predicted[step], found = guard.check(step, real, previous, f"batch [{label}]")
            previous = predicted[step]
            for violation in found:
                for index, (lo, hi) in enumerate(itertools.pairwise(ends)):
                    mine = violation.particles[(violation.particles >= lo) & (violation.particles < hi)] - lo
                    if mine.size:
                        violations[index].append(replace(violation, particles=mine))
    moving_host = moving.cpu().numpy()
    return [
        Rollout(
            truth=trajectory.first_frames(history + steps),
            predicted=predicted[:, lo:hi].numpy(),
            history=history,
            predicted_particles=moving_host[lo:hi],
            guard_violations=tuple(found),
        )
        for trajectory, lo, hi, found in zip(trajectories, ends[:-1], ends[1:], violations, strict=True)
    ]
