"""A training step of one scene split over several processes, with the gradients of the whole scene.

Each process holds the particles of its piece of the scene (:func:`owned_share`), fetches its halo
(positions, noise and targets of the particles within the receptive field, from the
processes that own them) and runs the model on owned plus halo particles. Only owned
particles enter its part of the loss, the squared error of their normalised
accelerations divided by the number of predicted particles in the whole scene: summed
over processes that is the single-process loss (Sanchez-Gonzalez et al. 2020, Sec. 3),
and an owned particle's prediction is the same function of the weights as in the whole
scene (the halo covers its receptive field), so the gradients summed over processes are
the single-process gradients. Then every process takes the same optimiser step.

Memory per process is its share of the scene's edges and latents plus the halo's: a scene
too large for one device trains on several.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

import torch
import torch.distributed as dist
from torch import Tensor

from ..data.batch import ParticleBatch
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_squared_error_sum
from ..runtime.precision import Precision, autocast, backward_precision
from .halo import with_halo
from .particles import Particles
from .partition import Partition
from .piece import on_piece

if TYPE_CHECKING:
    from ..runtime.processes import Processes


def owned_share(window: ParticleBatch, position_noise: Tensor, partition: Partition, rank: int) -> Particles:
    """The particles of a batch of training windows that process ``rank`` owns (by their last input position).

    The examples of a batch overlap in space; each keeps its own particles apart by its
    example index, as the graph builder does.

    Shapes: window (N, C, d) with ``next_position``; position_noise (N, C, d).
    """
    assert window.next_position is not None, "training windows, with their targets"
    everyone = Particles(
        torch.arange(window.num_particles, device=window.position_sequence.device),
        window.position_sequence,
        window.particle_type,
        window.material_property,
        window.next_position,
        position_noise,
        window.batch,
    )
    return everyone.select(partition.owner(window.position_sequence[:, -1]) == rank)


def partitioned_gradients(
    simulator: LearnedSimulator,
    owned: Particles,
    scene: ParticleBatch,
    partition: Partition,
    processes: Processes,
    halo: Literal["positions", "latents"] = "positions",
    precision: Precision = "float32",
    everyone: Processes | None = None,
) -> Tensor:
    """Forward and backward of this process's share, then the gradients summed over processes.

    Every process calls it at once. Afterwards every parameter's ``grad`` holds the gradient
    of the whole scene's loss (add to what was there: zero them before, as for a plain step).

    Args:
        owned: this process's particles, with ``next_position`` and ``noise``.
        scene: what the whole scene shares (``context``, ``bounds``, ``walls``); its particle fields are ignored.
        partition, halo: from :func:`.halo.partition_for`, the same on every process.
        precision: of the forward and backward (``training.precision``).
        everyone: the whole job when ``processes`` is one team of it, each team taking its own
            windows (data-parallel over teams, :func:`~gns_framework.runtime.teams.team_of`):
            the loss is then the mean over every team's predicted particles and the gradients
            are summed over the job. Default: ``processes``.

    Returns:
        the whole scene's loss (a detached scalar, the same on every process).
    """
    everyone = processes if everyone is None else everyone
    particles = with_halo(owned, partition, processes.world_size, processes.group)
    local, owned_rows = particles.local, particles.owned_rows
    moving = simulator.predicted_mask(local.particle_type)[owned_rows]
    predicted_count = everyone.sum(moving.sum().to(torch.float64))
    device = owned.sequence.device

    def loss_share(batch: ParticleBatch) -> Tensor:
        """This process's share of the loss, back-propagated: its predicted particles' error over the scene's count."""
        assert local.noise is not None, "the owned particles carry their training noise"
        with autocast(precision, device):
            prediction, target = simulator(batch, local.noise)
        error = masked_squared_error_sum(prediction[owned_rows].to(target.dtype), target[owned_rows], moving)
        share = error / predicted_count.clamp(min=1).to(error.dtype)
        with backward_precision(precision, device):
            share.backward()
        return share

    share = on_piece(simulator, particles, halo, scene, loss_share, backward=True)
    if share is None:
        share = torch.zeros((), device=device)
    _sum_gradients(simulator, everyone)
    return everyone.sum(share.detach())


def _sum_gradients(module: torch.nn.Module, processes: Processes) -> None:
    """Every parameter's gradient summed over processes (a process that owned nothing adds zeros)."""
    if not processes.distributed:
        return
    for parameter in module.parameters():
        if not parameter.requires_grad:
            continue
        if parameter.grad is None:
            parameter.grad = torch.zeros_like(parameter)
        dist.all_reduce(parameter.grad, group=processes.group)
