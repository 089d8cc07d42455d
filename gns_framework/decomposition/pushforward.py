"""Push-forward of training windows whose scenes are split over several processes.

Push-forward (Brandstetter et al. 2022) rolls each training window on k steps with the
model itself, without gradient, and trains on the true frame after them
(:meth:`gns_framework.training.step.TrainingStep.pushed_forward`). With
``training.partitions`` every process holds the whole batch's positions (a few floats per
particle) but only its piece's graph and latents, which is what a large scene cannot fit
on one device. So each unrolled step is a decomposed prediction, as in
:mod:`.rollout`: every process predicts the particles of its piece (slab or block) from them
plus a halo;
then every process receives every other's predictions, so all hold the same next frame
and cut the next step's pieces alike. No particle needs to migrate: the pieces are cut
afresh from the whole frame at every step.

Every owned particle's prediction is the one it gets in the whole batch (the halo
covers its receptive field), so the pushed-forward windows equal the single process's.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from ..data.batch import ParticleBatch
from ..model.history import advance_window
from ..model.learned_simulator import LearnedSimulator
from .exchange import rows_everywhere
from .halo import HaloKind, partition_for, with_halo
from .particles import Particles
from .partition import Cut
from .piece import on_piece

if TYPE_CHECKING:
    from ..runtime.processes import Processes


@torch.no_grad()
def partitioned_pushed_forward(
    simulator: LearnedSimulator,
    batch: ParticleBatch,
    steps: int,
    processes: Processes,
    halo: HaloKind = "auto",
    cut: Cut = "auto",
) -> ParticleBatch:
    """``batch`` with its inputs rolled ``steps`` on by the model, the scenes split over ``processes``.

    Every process calls it at once with the same batch, and gets the same result: the
    single process's push-forward (its inputs advanced by the model's predictions, the true
    frame after them as target). Kinematic particles follow their true positions. ``halo`` and
    ``cut`` choose the halo and the pieces (:func:`.halo.partition_for`).

    Shapes: batch (N, C, d) windows with ``next_position`` (N, d) and ``ahead`` (N, m, d), m >= ``steps``.
    """
    assert batch.next_position is not None and batch.ahead is not None, "windows drawn with push-forward steps"
    truth = torch.cat([batch.next_position[:, None], batch.ahead], dim=1)
    sequence = batch.position_sequence
    for k in range(steps):
        following = _decomposed_next_frame(
            simulator, replace(batch, position_sequence=sequence), truth[:, k], processes, halo, cut
        )
        sequence = advance_window(sequence, following)
    return replace(batch, position_sequence=sequence, next_position=truth[:, steps])


def _decomposed_next_frame(
    simulator: LearnedSimulator,
    batch: ParticleBatch,
    prescribed: Tensor,
    processes: Processes,
    halo: HaloKind,
    cut: Cut,
) -> Tensor:
    """(N, d) the next positions of every particle of ``batch``, each predicted by the process that owns it.

    The process predicts its piece's particles from them plus the halo, then every process
    sends its predictions to every other (an all-gather of rows, by global id).
    """
    world, rank = processes.world_size, processes.rank
    current = batch.position_sequence[:, -1]
    partition, kind = partition_for(simulator, current, world, halo, cut=cut, by_work=False)
    everyone = Particles(
        torch.arange(batch.num_particles, device=current.device),
        batch.position_sequence,
        batch.particle_type,
        batch.material_property,
        example=batch.batch,
    )
    owned = everyone.select(partition.owner(current) == rank)
    particles = with_halo(owned, partition, world, processes.group)
    on_mine = lambda mine: simulator.predict_next_position(mine, prescribed=prescribed[particles.local.ids])  # noqa: E731
    predicted = on_piece(simulator, particles, kind, batch, on_mine)
    predicted = current[:0] if predicted is None else predicted[particles.owned_rows]
    return rows_everywhere(owned.ids, predicted.to(current.dtype), batch.num_particles, world, processes.group)
