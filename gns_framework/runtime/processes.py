"""This process's place in a training job and the few collectives training needs.

One plain process (``world_size == 1``) is the default: then every collective is the identity and nothing touches
``torch.distributed``. Under torchrun (:mod:`.distributed` starts the process group) global rank 0 alone writes
checkpoints and talks to the tracker; on resume it reads the checkpoint and sends the state to the other ranks, so
only rank 0 needs the run folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn

from .device import is_cuda


@dataclass(frozen=True)
class Processes:
    """This process's place in the job; ``world_size == 1`` is a plain single-process run.

    Attributes:
        rank: rank in ``group`` (0 .. world_size - 1).
        world_size: processes in the job, over every node.
        local_rank: rank on this node; picks the GPU.
        restart_count: how many times torchrun restarted the workers (elastic restarts).
        group: the process group of the collectives; None: the whole job (a team's: :mod:`.teams`).
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    restart_count: int = 0
    group: Any = None

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_chief(self) -> bool:
        """Rank 0: writes checkpoints and logs."""
        return self.rank == 0

    def device(self, requested: torch.device, visible_gpus: int | None = None) -> torch.device:
        """One GPU per process on its node; CPU stays CPU.

        torchrun shows every rank all the node's GPUs: rank ``local_rank`` takes GPU ``local_rank``. Launchers that
        bind each rank to its own GPU (SLURM ``--gpus-per-task``, ``CUDA_VISIBLE_DEVICES`` per rank) show it fewer
        GPUs than ``local_rank + 1``: then its GPU is the first it sees. ``visible_gpus`` defaults to
        ``torch.cuda.device_count()``.
        """
        if not (self.distributed and is_cuda(requested)):
            return requested
        visible = torch.cuda.device_count() if visible_gpus is None else visible_gpus
        return torch.device("cuda", self.local_rank if self.local_rank < visible else 0)

    def wrap(self, module: nn.Module, device: torch.device) -> nn.Module:
        """``module`` behind DistributedDataParallel when distributed (its forward averages gradients)."""
        if not self.distributed:
            return module
        device_ids = [device.index] if is_cuda(device) else None
        return nn.parallel.DistributedDataParallel(module, device_ids=device_ids)

    def sum(self, tensor: Tensor) -> Tensor:
        """Sum of ``tensor`` over every rank (a copy; the input is untouched)."""
        total = tensor.clone()
        if self.distributed:
            dist.all_reduce(total, op=dist.ReduceOp.SUM, group=self.group)
        return total

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier(group=self.group)

    def broadcast(self, value: Any) -> Any:
        """Rank 0's ``value`` on every rank (any picklable object)."""
        if not self.distributed:
            return value
        box = [value]
        dist.broadcast_object_list(box, group=self.group, group_src=0)
        return box[0]
