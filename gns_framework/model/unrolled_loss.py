"""Training outputs through the model's own rollout: an unrolled training step's loss (backpropagation through time).

A one-step loss only ever shows the model true (or noised) histories, and a learned rollout drifts where every
single step was fitted. Here the model rolls each window on K steps after the next frame, with gradient through
them: step k's inputs are the window the model itself produced, and its target is the output that brings that
window to the true frame k steps after the next one. The error a step leaves in the window costs in the steps after
it, so the model is trained on errors that compound. With the semi-implicit Euler step, a step's output minus
target is its rolled position minus the true one (in normalised acceleration units).
"""

from __future__ import annotations

from typing import Protocol

import torch
from torch import Tensor

from ..contracts import Decoder, Integrator
from ..data.batch import ParticleBatch
from .history import advance_window
from .normalization import Stats
from .periodic import PeriodicBox


class Stepped(Protocol):
    """What of a learned simulator the unrolled loss uses (its class imports this module, so it is not named here)."""

    box: PeriodicBox | None
    decoder: Decoder
    integrator: Integrator
    output_stats: Stats

    def continuous(self, position_sequence: Tensor) -> Tensor: ...
    def predicted_mask(self, particle_type: Tensor) -> Tensor: ...
    def processed_latent(self, position_sequence: Tensor, batch: ParticleBatch) -> Tensor: ...


def unrolled_outputs(
    simulator: Stepped, batch: ParticleBatch, position_noise: Tensor, steps: int
) -> tuple[Tensor, Tensor]:
    """Predicted and target normalised outputs of the next frame and ``steps`` more, ((1 + steps) N, d) each.

    Step 0 is ``LearnedSimulator.forward``'s (noised inputs, target moved by the last input's noise); every
    target after it moves by the same noise, so the rollout is judged against the truth shifted as its start was.
    Kinematic particles follow their true positions.

    Args:
        batch: windows with ``next_position`` and at least ``steps`` frames ``ahead``.
        position_noise: (N, C, d), zero for kinematic particles.
    """
    assert batch.next_position is not None and batch.ahead is not None and batch.ahead.shape[1] >= steps
    true_frames = [batch.next_position, *batch.ahead[:, :steps].unbind(1)]
    sequence = simulator.continuous(batch.position_sequence)
    window, moved_by = sequence + position_noise, position_noise[:, -1]
    moving = simulator.predicted_mask(batch.particle_type)[:, None]
    true_position, predictions, targets = sequence[:, -1], [], []
    stats, integrator = simulator.output_stats, simulator.integrator
    for k, frame in enumerate(true_frames):
        true_position = frame if simulator.box is None else simulator.box.unwrap_next(true_position, frame)
        target_position = true_position + moved_by
        prediction = simulator.decoder(simulator.processed_latent(window, batch))
        predictions.append(prediction)
        targets.append(stats.normalize(integrator.target(window, target_position)))
        if k < steps:
            rolled = integrator.next_position(window, stats.denormalize(prediction.to(window.dtype)))
            window = advance_window(window, torch.where(moving, rolled, target_position))
    return torch.cat(predictions), torch.cat(targets)
