"""Autoregressive rollouts, guarded.

Every predicted frame passes a :class:`~gns_framework.model.rollout_guard.RolloutGuard`;
the result is a :class:`~gns_framework.data.rollout.Rollout`, the prediction beside
its ground truth, which :func:`gns_framework.io.rollout_file.write_rollout` saves,
refusing non-finite predictions unless told otherwise, so no NaN reaches a file
silently.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterator
from contextlib import closing, contextmanager
from dataclasses import replace

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from ..contracts import GraphBuilder
from ..data.batch import ParticleBatch, window
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import DatasetError
from ..runtime.allocator import keep_freed_memory
from ..runtime.device import is_cuda
from ..runtime.host_sync import avoids_read_backs
from ..runtime.precision import Precision, autocast
from .captured_steps import CapturedSteps
from .history import advance_window
from .learned_simulator import LearnedSimulator
from .rollout_guard import GuardViolation, RolloutGuard

CAPACITY_CHECK_EVERY = 8
"""Steps between reads of a fixed-capacity graph builder's overflow flag (one wait for the device each): the
steps since a check are redone when it finds a buffer was short, so their frames reach the guard only after it."""


@torch.inference_mode()
def rollout(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    steps: int | None = None,
    device: torch.device | str = "cpu",
    progress: bool = False,
    guard: RolloutGuard | None = None,
    precision: Precision = "float32",
    capture: bool = False,
) -> Rollout:
    """Predict ``steps`` frames from the first C of ``trajectory``.

    Returns the prediction beside ``trajectory``'s first C + ``steps`` frames, with
    the particles the model predicts and what the guard clamped (no metadata: the
    model does not know the dataset's).

    Kinematic particles follow their prescribed (ground-truth) positions; every other
    particle only ever sees its own predictions. ``guard`` checks every predicted
    frame (default: stop on non-finite positions, no domain check); it raises
    RolloutDiverged, or clamps and records the violations. ``precision`` picks the
    dtype of the model's products (:mod:`gns_framework.runtime.precision`); positions stay float32.

    Predicted and ground-truth frames stay on the host; on a GPU each predicted frame
    is copied without blocking and checked by the guard a few steps later
    (:class:`HostFrames`), so a ``stop`` names the step where the violation occurred
    after the model has run a few steps past it.

    ``capture``: run each step as a replay of one captured step (:mod:`.captured_steps`: a CUDA
    graph on CUDA, an emulation elsewhere, which is not faster); the step must not wait for the
    device, so the graph builder must be ``radius_fixed_capacity`` (``grid_cnn`` reads its grid's size back).
    """
    check_simulates(simulator, trajectory)
    guard = guard if guard is not None else RolloutGuard(simulator.setup)
    if trajectory.bounds is not None:
        guard = guard.with_bounds(trajectory.bounds)  # its own domain's walls, not the training data's
    device = torch.device(device)
    if device.type == "cpu":
        keep_freed_memory()
    history = simulator.setup.history
    available = trajectory.num_steps - history
    steps = available if steps is None else min(steps, available)
    if steps < 1:
        raise ValueError(
            f"trajectory {trajectory.key!r} has {trajectory.num_steps} frames; rollout needs more than {history}"
        )
    state = window(trajectory, 0, history, with_target=False).to(device)
    truth = torch.from_numpy(trajectory.position[history : history + steps])
    moving = simulator.predicted_mask(state.particle_type)
    # Only the kinematic particles' ground truth goes to the device, all frames at once; every frame
    # stays on the host (12 GB per 1000 frames of 1M particles in 3D would not fit beside the model).
    kinematic = (~moving).nonzero()[:, 0]
    kinematic_truth = truth[:, kinematic.cpu()].to(device)
    predicted = torch.empty_like(truth)
    context = None if trajectory.step_context is None else torch.from_numpy(trajectory.step_context).to(device)
    violations: list[GuardViolation] = []
    frames = HostFrames(device)

    def checked(step: int, raw: Tensor) -> None:
        """The guard's check of frame ``step`` on the host; it raises under ``stop``."""
        nonlocal violations
        previous = predicted[step - 1] if step > 0 else torch.from_numpy(trajectory.position[history - 1])
        predicted[step], found = guard.check(step, raw, previous, trajectory.key)
        violations += found

    bar = tqdm(total=steps, desc=f"rollout {trajectory.key}", unit="step", disable=not progress)
    predictions = sound_frames(
        simulator, guard, state, kinematic, kinematic_truth, steps, precision, context, capture, bar.update
    )
    with bar, closing(predictions):  # a guard's stop closes it: the builder checks its own builds again
        for step, next_position in predictions:
            for done, raw in frames.push(step, next_position):
                checked(done, raw)
    for done, raw in frames.drain():
        checked(done, raw)
    return Rollout(
        truth=trajectory.first_frames(history + steps),
        predicted=predicted.numpy(),
        history=history,
        predicted_particles=moving.cpu().numpy(),
        guard_violations=tuple(violations),
    )


def sound_frames(
    simulator: LearnedSimulator,
    guard: RolloutGuard,
    state: ParticleBatch,
    kinematic: Tensor,
    kinematic_truth: Tensor,
    steps: int,
    precision: Precision,
    context: Tensor | None = None,
    capture: bool | CapturedSteps = False,
    progress: Callable[[int], object] = lambda done: None,
) -> Generator[tuple[int, Tensor], None, None]:
    """``(step, predicted frame)`` of ``steps`` steps from ``state``, in order, each once its graph is known complete.

    Each step is :func:`rollout_step`; ``kinematic`` (K,) are the kinematic particles' rows and
    ``kinematic_truth`` (S, K, d) their next positions, ``context`` (T, F) the step context
    of every stored frame (the first C are the inputs). With a fixed-capacity graph builder the frames come in
    runs of :data:`CAPACITY_CHECK_EVERY`, after the check that their graphs had every edge; a run whose check
    fails is redone with grown buffers. With ``capture`` the steps replay one captured step
    (:class:`~.captured_steps.CapturedSteps`; given one, its capture), captured again when the buffers grow.
    ``progress(n)`` is told of every ``n`` steps done.
    """
    history = state.position_sequence.shape[1]
    builder = simulator.graph_builder

    def one_step(current: ParticleBatch, kinematic_next: Tensor) -> tuple[Tensor, Tensor]:
        return rollout_step(simulator, guard, current, kinematic, kinematic_next, precision)

    if isinstance(capture, CapturedSteps):  # a capacity class's capture, replayed by this batch too
        steps_of: CapturedSteps | None = capture.rebound(state)
    else:
        steps_of = captured_rollout_steps(simulator, guard, state, kinematic, precision) if capture else None
    sequence = state.position_sequence
    step, sound_step, sound_sequence = 0, 0, sequence
    unchecked: list[tuple[int, Tensor]] = []
    with capacity_checks(builder) as every:
        while step < steps:
            frame_context = None if context is None else context[history - 1 + step][None]
            if steps_of is not None:
                next_position, continued = steps_of(sequence, frame_context, kinematic_truth[step])
            else:
                current = replace(state, position_sequence=sequence, context=frame_context)
                next_position, continued = one_step(current, kinematic_truth[step])
            unchecked.append((step, next_position))
            sequence = advance_window(sequence, continued)
            step += 1
            if step % every and step < steps:
                continue
            if builder.overflowed():  # a graph since the last check lacked edges: redo those steps, buffers grown
                step, sequence = sound_step, sound_sequence
                unchecked.clear()
                if steps_of is not None:
                    steps_of.invalidate()  # the buffers' shapes changed
                continue
            yield from unchecked
            progress(step - sound_step)
            unchecked.clear()
            sound_step, sound_sequence = step, sequence


def captured_rollout_steps(
    simulator: LearnedSimulator, guard: RolloutGuard, state: ParticleBatch, kinematic: Tensor, precision: Precision
) -> CapturedSteps:
    """:func:`rollout_step` of ``state``'s particles, replayed from one capture (:class:`CapturedSteps`)."""

    def one_step(current: ParticleBatch, kinematic_next: Tensor) -> tuple[Tensor, Tensor]:
        return rollout_step(simulator, guard, current, kinematic, kinematic_next, precision)

    return CapturedSteps(one_step, state, simulator.graph_builder)


def rollout_step(
    simulator: LearnedSimulator,
    guard: RolloutGuard,
    current: ParticleBatch,
    kinematic: Tensor,
    kinematic_next: Tensor,
    precision: Precision,
) -> tuple[Tensor, Tensor]:
    """One step on the device: the predicted frame (N, d) float32 and the frame to continue from.

    ``kinematic`` (K,) are the kinematic particles' rows and ``kinematic_next`` (K, d)
    their prescribed next positions. Nothing here waits for the device but the graph
    builder's edge count (:mod:`gns_framework.runtime.host_sync`); the guard's report on the
    frame comes later, from its host copy.
    """
    last = current.position_sequence[:, -1]
    prescribed = last.index_copy(0, kinematic, kinematic_next.to(last.dtype))
    with autocast(precision, last.device):
        next_position = simulator.predict_next_position(current, prescribed=prescribed)
    next_position = next_position.to(torch.float32)
    return next_position, guard.continued(next_position, last)


@contextmanager
def capacity_checks(builder: GraphBuilder) -> Iterator[int]:
    """Steps between the rollout's reads of ``builder.overflowed()``: 1, or for a fixed-capacity builder
    :data:`CAPACITY_CHECK_EVERY`, its own checks deferred to the rollout meanwhile."""
    builder.checks_deferred = builder.fixed_capacity
    try:
        yield CAPACITY_CHECK_EVERY if builder.fixed_capacity else 1
    finally:
        builder.checks_deferred = False


class HostFrames:
    """Predicted frames copied to the host without making the host wait for each.

    On the CPU a frame is its own host copy and is handed back at once. On a GPU
    each frame is copied into one of ``lag`` page-locked buffers without blocking;
    a frame is handed back ``lag`` steps later, when its copy has long finished, so
    the host runs ahead of the device instead of waiting for it every step.
    (:func:`~gns_framework.runtime.host_sync.avoids_read_backs` picks the way.)
    """

    def __init__(self, device: torch.device, lag: int = 8):
        self.device = device
        self.lag = lag
        self.pending: list[tuple[int, Tensor, torch.cuda.Event | None]] = []
        self.free: list[Tensor] = []

    def push(self, step: int, frame: Tensor) -> list[tuple[int, Tensor]]:
        """Queue frame ``step``; returns the ``(step, host frame)`` pairs now ready, oldest first.

        A host frame handed back is valid until the next call (its buffer is then reused).
        """
        if not avoids_read_backs(self.device):
            return [(step, frame)]
        cuda = is_cuda(self.device)
        buffer = self.free.pop() if self.free else torch.empty(frame.shape, dtype=frame.dtype, pin_memory=cuda)
        buffer.copy_(frame, non_blocking=cuda)
        event = None
        if cuda:
            event = torch.cuda.Event()
            event.record()
        self.pending.append((step, buffer, event))
        return self._ready(len(self.pending) - self.lag)

    def drain(self) -> list[tuple[int, Tensor]]:
        """Every frame still queued."""
        return self._ready(len(self.pending))

    def _ready(self, count: int) -> list[tuple[int, Tensor]]:
        ready = []
        for step, buffer, event in self.pending[: max(count, 0)]:
            if event is not None:
                event.synchronize()
            ready.append((step, buffer))
            self.free.append(buffer)
        del self.pending[: max(count, 0)]
        return ready


def check_simulates(simulator: LearnedSimulator, trajectory: Trajectory) -> None:
    """Refuse a trajectory of another dimension or with particle types the model was not built for."""
    setup = simulator.setup
    where = f"trajectory {trajectory.key!r}"
    if trajectory.dim != setup.dim:
        raise DatasetError(f"{where}: position: has d = {trajectory.dim} but the model simulates dim = {setup.dim}")
    unknown = sorted(set(np.unique(trajectory.particle_type).tolist()) - set(setup.particle_types))
    if unknown:
        raise DatasetError(
            f"{where}: particle_type: ids {unknown} are not among the model's {list(setup.particle_types)}"
        )
