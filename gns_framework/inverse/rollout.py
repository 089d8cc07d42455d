"""A learned rollout that autograd can differentiate end to end, with gradient checkpointing.

The rollout of :mod:`gns_framework.model.rollout` runs under ``inference_mode`` and guards
every frame; this one keeps the graph from the unknowns (material properties, the
initial history) to every predicted frame. Kept whole, that graph holds every
message-passing activation of every step; with ``checkpoint_every = K`` only the state
at every K-th step is kept and each segment of K steps is recomputed during the
backward (Chen et al. 2016): peak memory falls from O(S) steps to O(S/K + K) for about
one more forward pass of work.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from ..data.batch import ParticleBatch
from ..model.history import advance_window
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout_guard import RolloutGuard


def _advance(
    simulator: LearnedSimulator,
    state: ParticleBatch,
    sequence: Tensor,
    material_property: Tensor | None,
    prescribed: Tensor,
    guard: RolloutGuard | None = None,
) -> tuple[Tensor, Tensor]:
    """Roll ``len(prescribed)`` steps on from ``sequence``.

    Shapes: sequence (N, C, d), prescribed (K, N, d) -> final sequence (N, C, d), predicted (K, N, d).
    """
    frames = []
    for next_prescribed in prescribed:
        current = replace(state, position_sequence=sequence, material_property=material_property)
        next_position = simulator.predict_next_position(current, prescribed=next_prescribed)
        if guard is not None:
            # The walls hold as in gns rollout: a particle put back has no gradient along the wall's normal.
            next_position = guard.continued(next_position, sequence[:, -1])
        frames.append(next_position)
        sequence = advance_window(sequence, next_position)
    return sequence, torch.stack(frames)


def differentiable_rollout(
    simulator: LearnedSimulator,
    state: ParticleBatch,
    prescribed: Tensor,
    checkpoint_every: int = 0,
    guard: RolloutGuard | None = None,
) -> Tensor:
    """Predicted positions of ``len(prescribed)`` steps, differentiable in ``state``'s tensors.

    Args:
        simulator: the trained model; its own parameters may be frozen.
        state: the first C frames (``position_sequence`` (N, C, d)), particle types and
            material properties (N, P); gradients flow to whichever of them require grad.
        prescribed: (S, N, d) positions whose kinematic rows the rollout follows (the
            observed trajectory's frames C .. C + S - 1); moving rows are ignored.
        checkpoint_every: K > 0 keeps only every K-th state and recomputes the steps
            between during the backward; 0 keeps every activation. Run the forward
            and the backward inside :func:`~gns_framework.runtime.activation_memory.activations_recomputed`
            so that hand-written backwards do not keep their activations either.
        guard: the model's rollout guard (``rollout.guard``), which puts particles that left the domain back
            as ``gns rollout`` does (:meth:`~gns_framework.model.rollout_guard.RolloutGuard.continued`); None: none.

    Returns:
        (S, N, d) predicted positions.
    """
    steps = prescribed.shape[0]
    size = checkpoint_every if checkpoint_every > 0 else steps
    sequence, material_property = state.position_sequence, state.material_property
    segments = []
    for start in range(0, steps, size):
        chunk = prescribed[start : start + size]
        if checkpoint_every > 0 and torch.is_grad_enabled():
            sequence, predicted = checkpoint(
                _advance, simulator, state, sequence, material_property, chunk, guard, use_reentrant=False
            )
        else:
            sequence, predicted = _advance(simulator, state, sequence, material_property, chunk, guard)
        segments.append(predicted)
    return torch.cat(segments)
