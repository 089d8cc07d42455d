"""Data-parallel training under torchrun: reading the job from the environment, starting and stopping the process group.

torchrun (single- or multi-node) starts one process per device and describes it in
the environment (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT,
TORCHELASTIC_RESTART_COUNT). Without those variables training runs as one plain
process and none of this touches ``torch.distributed``. The process's place in the
job, DDP wrapping and the collectives are :class:`~.processes.Processes`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from datetime import timedelta
from typing import TypeVar

import torch
import torch.distributed as dist

from ..errors import GnsError
from ..runtime.device import is_cuda
from ..runtime.processes import Processes

__all__ = [
    "Processes",
    "backend_for",
    "from_chief",
    "process_group_timeout",
    "processes_from_environment",
    "start",
    "stop",
]

T = TypeVar("T")


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


def from_chief(processes: Processes, compute: Callable[[], T]) -> T:
    """``compute()`` run by rank 0 alone, and its result on every rank; its failure, raised on every rank.

    For what every rank needs and one can derive (the dataset's statistics and
    scene): read once, not once per rank. A failure is sent as well as raised (rank
    0 raises its own error, the others a GnsError or RuntimeError with its message),
    so no rank waits forever for a result that will not come.
    """
    if not processes.distributed:
        return compute()
    outcome: tuple[T | None, tuple[bool, str] | None] = (None, None)
    if processes.is_chief:
        try:
            outcome = (compute(), None)
        except Exception as exc:
            processes.broadcast((None, (isinstance(exc, GnsError), str(exc))))
            raise
    value, failure = processes.broadcast(outcome)
    if failure is not None:
        ours, message = failure
        raise (GnsError if ours else RuntimeError)(f"rank 0 failed: {message}")
    return value
