"""Validation of a model whose scenes are split over several processes (``training.partitions``).

A scene too large for one device to train on is often too large to validate on one, too: a
rollout holds the graph of the whole scene at every step. So a split run validates split, with
the measures of :class:`gns_framework.training.validation.Validation` taken piece by piece:

- the one-step errors on the fixed windows: each process predicts its piece's particles from
  them plus the halo (:mod:`.halo`), and the squared errors and predicted-particle counts are
  summed over the processes, so the means are the whole batch's;
- the rollouts: :func:`.rollout.partitioned_rollout`, whose frames rank 0 gathers and scores.

Every process calls these at once; rank 0 gets the results the single process would.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from ..data.batch import ParticleBatch
from ..data.trajectory import Trajectory
from ..errors import RolloutDiverged
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_squared_error_sum
from .halo import HaloKind, partition_for, with_halo
from .partition import Cut
from .piece import on_piece
from .rollout import partitioned_rollout
from .training_step import owned_share

if TYPE_CHECKING:
    from ..runtime.processes import Processes


@torch.no_grad()
def partitioned_one_step_errors(
    simulator: LearnedSimulator,
    batch: ParticleBatch,
    processes: Processes,
    halo: HaloKind = "auto",
    cut: Cut = "auto",
) -> tuple[float, float]:
    """(one-step loss, next-position MSE) of noise-free windows, the scenes split over ``processes``.

    The loss is the squared error of the normalised accelerations summed over dimensions and
    averaged over the predicted particles (L^0); the MSE is that of the next positions,
    averaged over predicted particles and dimensions (L^2): both as one process measures
    them on the whole batch.

    Shapes: batch (N, C, d) windows with ``next_position`` (N, d).
    """
    assert batch.next_position is not None, "validation windows have their target"
    world, rank = processes.world_size, processes.rank
    partition, kind = partition_for(simulator, batch.position_sequence[:, -1], world, halo, cut=cut, by_work=False)
    owned = owned_share(batch, torch.zeros_like(batch.position_sequence), partition, rank)
    particles = with_halo(owned, partition, world, processes.group)
    local, owned_rows = particles.local, particles.owned_rows

    def error_sums(mine: ParticleBatch) -> Tensor:
        """The owned particles' acceleration error, position error and count (float64, to be summed over processes)."""
        assert local.noise is not None and local.next_position is not None
        prediction, target = simulator(mine, local.noise)
        moving = simulator.predicted_mask(local.particle_type)[owned_rows]
        acceleration = masked_squared_error_sum(prediction[owned_rows], target[owned_rows], moving)
        accelerations = simulator.output_stats.denormalize(prediction)
        next_position = simulator.integrator.next_position(local.sequence, accelerations)[owned_rows]
        position = ((next_position - local.next_position[owned_rows])[moving] ** 2).sum()
        return torch.stack([acceleration.double(), position.double(), moving.sum().double()])

    sums = on_piece(simulator, particles, kind, batch, error_sums)
    if sums is None:
        sums = torch.zeros(3, dtype=torch.float64, device=batch.position_sequence.device)
    acceleration_sum, position_sum, predicted = processes.sum(sums).tolist()
    predicted = max(predicted, 1.0)
    return acceleration_sum / predicted, position_sum / (predicted * batch.position_sequence.shape[-1])


def partitioned_positions(
    processes: Processes, device: torch.device | str, halo: HaloKind = "auto", cut: Cut = "auto"
) -> Callable[[LearnedSimulator, Trajectory], np.ndarray | None]:
    """``positions(simulator, trajectory)``: on rank 0 the (S, N, d) positions of a rollout split over
    ``processes``, None on the others.

    As for one process (:func:`gns_framework.evaluation.candidates.learned_positions`), a
    diverged rollout is a result, not an error: its positions are NaN, which the metrics count
    as diverged with infinite error.
    """

    def positions(simulator: LearnedSimulator, trajectory: Trajectory) -> np.ndarray | None:
        try:
            result, _ = partitioned_rollout(simulator, trajectory, processes, device=device, halo=halo, cut=cut)
        except RolloutDiverged:
            if not processes.is_chief:
                return None
            shape = (trajectory.num_steps - simulator.setup.history, *trajectory.position.shape[1:])
            return np.full(shape, np.nan, dtype=trajectory.position.dtype)
        return None if result is None else result.predicted

    return positions
