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

from ..data.batch import ParticleBatch
from ..decomposition.halo import slabs_for
from ..decomposition.training_step import owned_share, partitioned_gradients
from .step import TrainingStep


class PartitionedTrainingStep(TrainingStep):
    """:class:`TrainingStep` for scenes split into slabs, one per process (no push-forward): the
    same windows, noise and update, with the gradients computed slab by slab.

    Built as a TrainingStep whose ``model`` is the bare simulator and whose window order
    is the one of a single process (every process takes every window of the step).
    """

    def gradients(self, batch: ParticleBatch, noise: Tensor, mask: Tensor) -> Tensor:
        """Fresh gradients of the whole batch's loss on every process, each computing its slab's share."""
        partition, halo = slabs_for(self.simulator, batch.position_sequence[:, -1], self.processes.world_size)
        owned = owned_share(batch, noise, partition, self.processes.rank)
        self.optimizer.zero_grad(set_to_none=True)
        loss = partitioned_gradients(self.simulator, owned, batch, partition, self.processes, halo, self.precision)
        return loss.to(torch.float64)
