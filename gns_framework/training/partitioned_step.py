"""The optimisation step with each scene split over the processes (``training.partitions``).

Every process takes the same windows of the step (the whole batch, with the same noise),
owns the particles in its piece of the scene (a slab or a block), rolls the windows on with the others where the step
pushes them forward (:func:`gns_framework.decomposition.pushforward.partitioned_pushed_forward`), and computes the
gradients of the whole batch's loss with the others
(:func:`gns_framework.decomposition.training_step.partitioned_gradients`). The weights, the optimiser, the schedule and
the weight average then take the same update on every process, so the run is one process's run, with the memory of each
scene split.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..data.batch import ParticleBatch
from ..decomposition.halo import partition_for
from ..decomposition.pushforward import partitioned_pushed_forward
from ..decomposition.training_step import owned_share, partitioned_gradients
from ..runtime.processes import Processes
from .step import TrainingStep


class PartitionedTrainingStep(TrainingStep):
    """:class:`TrainingStep` for scenes split into pieces, one per process of a team: the same
    windows, noise, push-forward and update, with the unrolled steps and the gradients computed
    piece by piece.

    Built as a TrainingStep whose ``model`` is the bare simulator and whose window order
    is that of data-parallel teams (every process of a team takes its team's windows). With
    one team, the job, it is a single process's order.

    Args:
        team: this process's team (:func:`~.teams.team_of`), one process per piece;
            ``processes`` is the whole job, over which the gradients are summed.
    """

    def __init__(self, *args, team: Processes, **kwargs):
        super().__init__(*args, **kwargs)
        self.team = team

    def gradients(self, batch: ParticleBatch, noise: Tensor, mask: Tensor) -> Tensor:
        """Fresh gradients of the global batch's loss on every process, each computing its piece's share."""
        position = batch.position_sequence[:, -1]
        partition, halo = partition_for(self.simulator, position, self.team.world_size, by_work=False)
        owned = owned_share(batch, noise, partition, self.team.rank)
        self.optimizer.zero_grad(set_to_none=True)
        loss = partitioned_gradients(
            self.simulator, owned, batch, partition, self.team, halo, self.precision, everyone=self.processes
        )
        return loss.to(torch.float64)

    def pushed_forward(self, batch: ParticleBatch, steps: int) -> ParticleBatch:
        """The single process's push-forward, each unrolled step predicted piece by piece (the same batch in the
        team)."""
        return partitioned_pushed_forward(self.simulator, batch, steps, self.team)
