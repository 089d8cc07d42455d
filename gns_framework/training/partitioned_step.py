"""The optimisation step with each scene split over the processes (``training.partitions``).

Every process takes the same windows of the step (the whole batch, with the same noise),
owns the particles in its slab, and computes the gradients of the whole batch's loss
with the others (:func:`gns_framework.decomposition.training_step.partitioned_gradients`).
The weights, the optimiser, the schedule and the weight average then take the same update
on every process, so the run is one process's run, with the memory of each scene split.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..decomposition.halo import slabs_for
from ..decomposition.training_step import owned_share, partitioned_gradients
from .step import TrainingStep


class PartitionedTrainingStep(TrainingStep):
    """:class:`TrainingStep` for scenes split into slabs, one per process (no push-forward).

    Built as a TrainingStep whose ``model`` is the bare simulator and whose window order
    is the one of a single process (every process takes every window of the step).
    """

    def __call__(self, step: int) -> tuple[Tensor, int]:
        batch = self.windows.batch(self.order.indices(step))
        noise = self.noise(step)
        if self.pins_memory:
            batch, noise = batch.pinned(), noise.pin_memory()
        batch = batch.to(self.device)
        mask = self.simulator.predicted_mask(batch.particle_type)
        noise = noise.to(self.device, non_blocking=True) * mask[:, None, None]
        partition, halo = slabs_for(self.simulator, batch.position_sequence[:, -1], self.processes.world_size)
        owned = owned_share(batch, noise, partition, self.processes.rank)
        self.optimizer.zero_grad(set_to_none=True)
        loss = partitioned_gradients(self.simulator, owned, batch, partition, self.processes, halo, self.precision)
        self.optimizer.step()
        if self.ema is not None:
            self.ema.update(self.simulator)
        self.scheduler.step()
        particles = sum(self.windows.num_particles(self.order.window_at(p)) for p in self.order.step_positions(step))
        return loss.to(torch.float64), particles
