"""An inverse problem: which unknowns make the learned rollout reproduce an observed trajectory.

The unknowns are gathered in one vector ``u`` in [0, 1]^k, each scaled over its bounds,
so one optimiser step size fits a friction coefficient and a velocity in m/s alike.
:meth:`InverseProblem.loss` maps ``u`` to the rollout's misfit, differentiably:

    u -> values (friction, velocity, ...) -> model inputs (material_property, history)
      -> learned rollout from the observed first C frames -> loss against the observation

The observed trajectory's own value of an unknown is never read: a property column is
overwritten for the particles it concerns, and an unknown initial velocity rebuilds
their C input frames from the first observed frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from ..data.batch import ParticleBatch, collate, window
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..errors import RecipeError
from ..evaluation.metrics import ParticleRollout, domain_size, runout_distance, sinkhorn_distance
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout_guard import RolloutGuard
from .config import INITIAL_VELOCITY, InvertConfig, PropertyUnknown, VelocityUnknown
from .rollout import differentiable_rollout

LOSS_UNITS = {
    "positions": "L^2, position MSE over the observed frames and moving particles",
    "runout": "%, |predicted - observed| runout at the last observed frame, of the observed runout",
    "sinkhorn": "%, Sinkhorn distance between the final particle clouds, of the domain size",
}
SINKHORN_BLUR_FRACTION = 1e-3
"""Blur of the Sinkhorn loss as a share of the domain size: the evaluation metric's."""


@dataclass(frozen=True)
class Parameters:
    """Names and bounds of the scalar unknowns, in the order of the vector ``u``.

    Shapes: low, high (k,).
    """

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray

    def values(self, u: Tensor) -> Tensor:
        """(k,) physical values of the scaled vector ``u`` in [0, 1]^k."""
        low = torch.as_tensor(self.low, dtype=u.dtype, device=u.device)
        high = torch.as_tensor(self.high, dtype=u.dtype, device=u.device)
        return low + u * (high - low)

    def scaled(self, values: Sequence[float]) -> np.ndarray:
        """``u`` of physical ``values``; an axis fixed by equal bounds sits at 0.5 (its gradient is 0)."""
        width = self.high - self.low
        fixed = width == 0
        return np.where(fixed, 0.5, (np.asarray(values, dtype=np.float64) - self.low) / np.where(fixed, 1.0, width))

    def as_record(self, values: Sequence[float], unknowns: dict) -> dict:
        """``{"friction": 0.71, "initial_velocity": [1.2, 0.0]}``: values grouped by unknown."""
        record, index = {}, 0
        for name, unknown in unknowns.items():
            width = len(unknown.start)
            chunk = [float(v) for v in values[index : index + width]]
            record[name] = chunk if isinstance(unknown, VelocityUnknown) else chunk[0]
            index += width
        return record


def parameters_of(unknowns: dict[str, PropertyUnknown | VelocityUnknown]) -> tuple[Parameters, np.ndarray]:
    """The scaled layout of ``unknowns`` and its starting vector ``u0``."""
    names, low, high, start = [], [], [], []
    for name, unknown in unknowns.items():
        if isinstance(unknown, VelocityUnknown):
            names += [f"{name}.{axis}" for axis in "xyz"[: len(unknown.bounds)]]
            low += [b[0] for b in unknown.bounds]
            high += [b[1] for b in unknown.bounds]
        else:
            names.append(name)
            low.append(unknown.bounds[0])
            high.append(unknown.bounds[1])
        start += unknown.start
    parameters = Parameters(tuple(names), np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64))
    return parameters, parameters.scaled(start)


def check_against_model(
    config: InvertConfig,
    unknowns: dict[str, PropertyUnknown | VelocityUnknown],
    simulator: LearnedSimulator,
    trajectories: Sequence[Trajectory],
    source: str | Path,
) -> None:
    """Every problem only the model and the data reveal, at once: RecipeError naming each field."""
    setup = simulator.setup
    problems: list[tuple[str, str]] = []
    for name, unknown in unknowns.items():
        where = f"unknowns.{name}"
        if isinstance(unknown, VelocityUnknown):
            if len(unknown.bounds) != setup.dim:
                problems.append(
                    (
                        f"{where}.bounds",
                        f"needs {setup.dim} [low, high] pairs (one per axis), got {len(unknown.bounds)}",
                    )
                )
        elif name not in setup.property_names:
            inputs = ", ".join(setup.property_names) if setup.property_names else "none"
            problems.append(
                (
                    where,
                    f"the model has no input {name!r}: it was trained with the material properties: "
                    f"{inputs} (or use {INITIAL_VELOCITY})",
                )
            )
        kind = unknown.particle_type
        if kind is not None:
            if kind not in setup.particle_types:
                problems.append(
                    (
                        f"{where}.particle_type",
                        f"{kind} is not among the model's particle types {list(setup.particle_types)}",
                    )
                )
            elif kind in setup.kinematic_types:
                problems.append((f"{where}.particle_type", f"{kind} is kinematic: the model does not move it"))
    observed = config.observed
    if observed.trajectory >= len(trajectories):
        problems.append(
            (
                "observed.trajectory",
                f"{observed.trajectory} is out of range: split {observed.split!r} "
                f"of {observed.dataset} holds {len(trajectories)} trajectories (0 .. {len(trajectories) - 1})",
            )
        )
    else:
        trajectory = trajectories[observed.trajectory]
        frames = trajectory.num_steps
        for field, listed in (("frames", observed.frames), ("held_out", observed.held_out)):
            if isinstance(listed, list):
                bad = [f for f in listed if not setup.history <= f < frames]
                if bad or not listed:
                    problems.append(
                        (
                            f"observed.{field}",
                            f"frames {bad or '[]'} are not rolled out: give indices in "
                            f"[{setup.history}, {frames - 1}] (the first {setup.history} are the model's input)",
                        )
                    )
        if not isinstance(observed.frames, list) and frames <= setup.history:
            problems.append(
                (
                    "observed.trajectory",
                    f"has {frames} frames; the model needs more than its {setup.history} input frames",
                )
            )
        for name, unknown in unknowns.items():
            kind = unknown.particle_type
            if kind is not None and kind in setup.particle_types and not (trajectory.particle_type == kind).any():
                problems.append(
                    (f"unknowns.{name}.particle_type", f"no particle of type {kind} in trajectory {trajectory.key!r}")
                )
        if setup.property_names and trajectory.material_property is None:
            missing = [p for p in setup.property_names if p not in unknowns]
            if missing:
                problems.append(
                    (
                        "observed.dataset",
                        f"trajectory {trajectory.key!r} has no material_property, and the "
                        f"model needs {missing} besides the unknowns",
                    )
                )
    if problems:
        raise RecipeError(source, problems)


def observed_frames(frames: Literal["last", "all"] | list[int], history: int, num_frames: int) -> list[int]:
    """Trajectory frame indices the loss compares, sorted."""
    if frames == "last":
        return [num_frames - 1]
    if frames == "all":
        return list(range(history, num_frames))
    return sorted(set(frames))


class InverseProblem:
    """The loss of an observed trajectory as a differentiable function of the scaled unknowns.

    ``u`` is one point (k,) or M points (M, k), searched together: the M rollouts run as
    one batch (each start a copy of the scene, never connected to the others), so M
    starts cost one model call per step instead of M.

    Args:
        simulator: the trained model (its parameters are frozen here).
        trajectory: the observed trajectory, as the model sees it (frame stride applied).
        metadata: of the observed dataset (``dt`` between the model's frames, bounds).
        unknowns: the typed unknowns, by name.
        loss: ``positions``, ``runout`` or ``sinkhorn`` (:data:`LOSS_UNITS`).
        frames: observed frame indices the loss compares (:func:`observed_frames`).
        granular_types: particle types whose runout counts (default: every moving type).
        checkpoint_every: gradient checkpointing interval in rollout steps (0: none).
        dtype: float32, or float64 for gradient checks.
        held_out: observed frame indices kept out of the loss; :meth:`losses` gives the same
            misfit on them, from the same rollout, to choose the best iterate by.
        guard: the model's rollout guard: walls hold as in ``gns rollout`` (None: no walls).
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        trajectory: Trajectory,
        metadata: DatasetMetadata,
        unknowns: dict[str, PropertyUnknown | VelocityUnknown],
        loss: str,
        frames: Sequence[int],
        granular_types: Sequence[int] = (),
        checkpoint_every: int = 0,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        held_out: Sequence[int] = (),
        guard: RolloutGuard | None = None,
    ):
        self.simulator = simulator.requires_grad_(False)
        self.guard = guard.with_bounds(trajectory.bounds) if guard and trajectory.bounds is not None else guard
        self.trajectory = trajectory
        self.metadata = metadata
        self.unknowns = unknowns
        self.loss_name = loss
        self.frames = list(frames)
        self.held_out = sorted(set(held_out))
        self.checkpoint_every = checkpoint_every
        self.parameters, self.start = parameters_of(unknowns)
        setup = simulator.setup
        history = setup.history
        self.steps = max(self.frames + self.held_out) - history + 1
        self.dtype = dtype
        state = window(trajectory, 0, history, with_target=False).to(device)
        material_property = state.material_property
        if material_property is None and setup.property_names:
            # Every column the model reads is an unknown here (checked): start from the properties' defaults.
            material_property = torch.zeros(state.num_particles, len(setup.property_names), device=device)
        # The observation's own box and wall conditions stay: the model takes them from the data.
        self.state = replace(
            state,
            position_sequence=state.position_sequence.to(dtype),
            material_property=None if material_property is None else material_property.to(dtype),
        )
        self.observed = torch.from_numpy(trajectory.position[history : history + self.steps]).to(device, dtype)
        self.prescribed = self.observed
        self.moving = simulator.predicted_mask(state.particle_type)
        kinds = list(granular_types) or sorted(set(state.particle_type[self.moving].tolist()))
        self.granular = torch.isin(state.particle_type, torch.tensor(kinds, device=device)) & self.moving
        self.first_frame = self.state.position_sequence[:, 0]
        self.domain = domain_size(metadata.bounds)
        self._copies: dict[int, ParticleBatch] = {1: self.state}

    def _copies_of_the_scene(self, starts: int) -> ParticleBatch:
        """The observed start stacked ``starts`` times, one example per start (cached)."""
        if starts not in self._copies:
            self._copies[starts] = collate([self.state] * starts)
        return self._copies[starts]

    def model_inputs(self, u: Tensor) -> ParticleBatch:
        """The rollout's starting state with the unknowns' values in place of the observed ones.

        Shapes: u (k,) -> a batch of the N observed particles; u (M, k) -> M examples, M N particles.
        """
        points = u[None] if u.ndim == 1 else u
        state = self._copies_of_the_scene(points.shape[0])
        # Every particle reads the values of its own start: (M, k) -> (M N, k).
        values = self.parameters.values(points).to(self.dtype)[state.batch]
        sequence, material_property = state.position_sequence, state.material_property
        first_frame = sequence[:, 0]
        index = 0
        setup = self.simulator.setup
        for name, unknown in self.unknowns.items():
            width = len(unknown.start)
            value = values[:, index : index + width]
            index += width
            if isinstance(unknown, VelocityUnknown):
                # C input frames of a body starting at the unknown velocity from the first observed frame,
                # accelerated by the given gravity (ballistic flight) or not at all (uniform motion).
                times = torch.arange(setup.history, dtype=self.dtype, device=u.device)[None, :, None] * self.metadata.dt
                gravity = torch.tensor(unknown.gravity or [0.0] * setup.dim, dtype=self.dtype, device=u.device)
                rebuilt = first_frame[:, None] + times * value[:, None] + 0.5 * times.square() * gravity
                chosen = (state.particle_type == unknown.particle_type)[:, None, None]
                sequence = torch.where(chosen, rebuilt, sequence)
            else:
                assert (
                    material_property is not None
                )  # a property unknown: the model has properties (zeros if unrecorded)
                chosen = self._particles(unknown, state.particle_type)[:, None]
                column = torch.zeros(len(setup.property_names), dtype=torch.bool, device=u.device)
                column[setup.property_names.index(name)] = True
                material_property = torch.where(chosen & column, value, material_property)
        return replace(state, position_sequence=sequence, material_property=material_property)

    def _particles(self, unknown: PropertyUnknown, particle_type: Tensor) -> Tensor:
        if unknown.particle_type is None:
            return self.simulator.predicted_mask(particle_type)
        return particle_type == unknown.particle_type

    def rollout(self, u: Tensor) -> tuple[ParticleBatch, Tensor]:
        """The starting state and the (S, N, d) predicted positions for the scaled unknowns ``u``.

        With M points ``u`` (M, k), the predictions are (S, M N, d): start after start.
        """
        state = self.model_inputs(u)
        starts = state.num_examples
        prescribed = self.prescribed.repeat(1, starts, 1) if starts > 1 else self.prescribed
        return state, differentiable_rollout(self.simulator, state, prescribed, self.checkpoint_every, self.guard)

    def loss(self, u: Tensor) -> Tensor:
        """The scalar misfit (units in :data:`LOSS_UNITS`) of the rollout from ``u``; (M,) for M points."""
        state, predicted = self.rollout(u)
        loss = self.misfit(state, predicted)
        return loss[0] if u.ndim == 1 else loss

    def losses(self, u: Tensor) -> tuple[Tensor, Tensor | None]:
        """The loss and, from the same rollout, the misfit on the held-out frames (detached; None without any).

        Shapes: u (k,) -> two scalars; u (M, k) -> (M,) and (M,), one per start.
        """
        state, predicted = self.rollout(u)
        loss = self.misfit(state, predicted)
        held_out = None
        if self.held_out:
            with torch.no_grad():
                held_out = self.misfit(state, predicted.detach(), self.held_out).detach()
        if u.ndim == 1:
            return loss[0], None if held_out is None else held_out[0]
        return loss, held_out

    def misfit(self, state: ParticleBatch, predicted: Tensor, frames: Sequence[int] | None = None) -> Tensor:
        """(M,) the loss of each start on ``frames`` (default: the frames the loss compares).

        Shapes: predicted (S, M N, d) -> (M,).
        """
        history = self.simulator.setup.history
        index = [f - history for f in (self.frames if frames is None else frames)]
        starts = state.num_examples
        n = self.state.num_particles
        # (F, M, N, d): each start's frames beside the one observation.
        compared, target = predicted[index].unflatten(1, (starts, n)), self.observed[index][:, None]
        if self.loss_name == "positions":
            return (compared - target)[:, :, self.moving].square().mean(dim=(0, 2, 3))
        final, observed_final = compared[-1], target[-1].expand(starts, -1, -1)
        if self.loss_name == "sinkhorn":
            weight = self.moving[None].expand(starts, -1)
            distance = sinkhorn_distance(
                final,
                observed_final,
                weight,
                weight,
                blur=SINKHORN_BLUR_FRACTION * self.domain,
                diameter=self.domain,
            )
            return 100 * distance / self.domain
        kinematic = self.simulator.setup.kinematic_types
        types = self.state.particle_type[None].expand(starts, -1)
        granular = self.granular[None].expand(starts, -1)
        start = state.position_sequence[:, 0].unflatten(0, (starts, n))
        predicted_runout = runout_distance(
            ParticleRollout.of(final[:, None], types, start=start, kinematic_types=kinematic), granular
        )
        observed_runout = runout_distance(
            ParticleRollout.of(
                observed_final[:, None],
                types,
                start=self.first_frame[None].expand(starts, -1, -1),
                kinematic_types=kinematic,
            ),
            granular,
        )
        return 100 * (predicted_runout - observed_runout).abs() / observed_runout.abs()
