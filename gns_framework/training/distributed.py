"""Data-parallel training under torchrun: process group, DDP wrapping and the few collectives training needs.

torchrun (single- or multi-node) starts one process per device and describes it in
the environment (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT,
TORCHELASTIC_RESTART_COUNT). Without those variables training runs as one plain
process and none of this touches ``torch.distributed``.

Global rank 0 alone writes checkpoints and talks to the tracker; on resume it reads
the checkpoint and sends the state to the other ranks, so only rank 0 needs the run
folder.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn

from ..runtime.device import is_cuda


@dataclass(frozen=True)
class Processes:
    """This process's place in the job; ``world_size == 1`` is a plain single-process run.

    Attributes:
        rank: global rank (0 .. world_size - 1).
        world_size: processes in the job, over every node.
        local_rank: rank on this node; picks the GPU.
        restart_count: how many times torchrun restarted the workers (elastic restarts).
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    restart_count: int = 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_chief(self) -> bool:
        """Rank 0: writes checkpoints and logs."""
        return self.rank == 0

    def device(self, requested: torch.device, visible_gpus: int | None = None) -> torch.device:
        """One GPU per process on its node; CPU stays CPU.

        torchrun shows every rank all the node's GPUs: rank ``local_rank`` takes GPU
        ``local_rank``. Launchers that bind each rank to its own GPU (SLURM
        ``--gpus-per-task``, ``CUDA_VISIBLE_DEVICES`` per rank) show it fewer GPUs
        than ``local_rank + 1``: then its GPU is the first it sees. ``visible_gpus``
        defaults to ``torch.cuda.device_count()``.
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
            dist.all_reduce(total, op=dist.ReduceOp.SUM)
        return total

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier()

    def broadcast(self, value: Any) -> Any:
        """Rank 0's ``value`` on every rank (any picklable object)."""
        if not self.distributed:
            return value
        box = [value]
        dist.broadcast_object_list(box, src=0)
        return box[0]


def processes_from_environment(environ: dict[str, str] | None = None) -> Processes:
    """The torchrun variables of this process, or a single process when they are absent."""
    env = os.environ if environ is None else environ
    world_size = int(env.get("WORLD_SIZE", "1"))
    if world_size < 1:
        raise ValueError(f"WORLD_SIZE={world_size}: must be at least 1")
    return Processes(
        rank=int(env.get("RANK", "0")),
        world_size=world_size,
        local_rank=int(env.get("LOCAL_RANK", "0")),
        restart_count=int(env.get("TORCHELASTIC_RESTART_COUNT", "0")),
    )


PROCESS_GROUP_TIMEOUT_S = 3600.0
"""How long a collective waits for the other ranks by default (``GNS_PROCESS_GROUP_TIMEOUT_S``).

Rank 0 alone validates (rollouts) and writes checkpoints while the other ranks wait at
the next collective; NCCL's own default (10 minutes) can end a run whose validation
takes longer, and gloo's (30 minutes) one with long rollouts. An hour covers the
validation of large scenes and still ends a job whose rank has died."""


def process_group_timeout(environ: dict[str, str] | None = None) -> timedelta:
    """The process group's timeout: ``GNS_PROCESS_GROUP_TIMEOUT_S`` seconds, else :data:`PROCESS_GROUP_TIMEOUT_S`."""
    env = os.environ if environ is None else environ
    raw = env.get("GNS_PROCESS_GROUP_TIMEOUT_S", "")
    try:
        seconds = float(raw) if raw.strip() else PROCESS_GROUP_TIMEOUT_S
    except ValueError:
        raise ValueError(f"GNS_PROCESS_GROUP_TIMEOUT_S={raw!r}: must be a number of seconds") from None
    if not seconds > 0:
        raise ValueError(f"GNS_PROCESS_GROUP_TIMEOUT_S={raw!r}: must be positive")
    return timedelta(seconds=seconds)


def backend_for(device: torch.device) -> str:
    """nccl between GPUs, gloo between CPU processes."""
    return "nccl" if is_cuda(device) else "gloo"


def start(processes: Processes, device: torch.device) -> torch.device:
    """Join the process group (torchrun's env:// rendezvous) and return this process's device."""
    device = processes.device(device)
    if processes.distributed and not dist.is_initialized():
        if is_cuda(device):
            torch.cuda.set_device(device)
        store, _, _ = next(dist.rendezvous("env://", processes.rank, processes.world_size))
        # torchrun can keep one store across elastic restarts; without a per-attempt prefix a
        # restarted worker may read a dead worker's address and fail to connect.
        store = dist.PrefixStore(f"gns/attempt-{processes.restart_count}", store)
        # device_id binds NCCL's communicator to this rank's GPU at once, instead of guessing it
        # at the first collective (which picks by rank and collides when each rank sees one GPU).
        dist.init_process_group(
            backend=backend_for(device),
            store=store,
            rank=processes.rank,
            world_size=processes.world_size,
            device_id=device if is_cuda(device) else None,
            timeout=process_group_timeout(),
        )
    return device


def stop() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
