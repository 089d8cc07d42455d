"""A process's place in the job: which GPU it takes, and collectives that are the identity for one process.

The collectives across real processes are tested under torchrun in test_distributed.py.
"""

from __future__ import annotations

import torch
from torch import nn

from gns_framework.runtime.processes import Processes


def test_rank_zero_is_the_chief_and_one_process_is_not_distributed():
    assert Processes().is_chief and not Processes().distributed
    assert Processes(rank=0, world_size=2).is_chief and Processes(rank=0, world_size=2).distributed
    assert not Processes(rank=1, world_size=2).is_chief


def test_each_rank_takes_the_gpu_of_its_local_rank():
    processes = Processes(rank=5, world_size=8, local_rank=1)
    assert processes.device(torch.device("cuda"), visible_gpus=4) == torch.device("cuda", 1)
    assert Processes().device(torch.device("cuda"), visible_gpus=4) == torch.device("cuda"), (
        "one process keeps its choice"
    )


def test_a_rank_shown_one_gpu_takes_it():
    """SLURM --gpus-per-task shows each rank only its GPU: LOCAL_RANK 1 must not ask for cuda:1."""
    processes = Processes(rank=1, world_size=2, local_rank=1)
    assert processes.device(torch.device("cuda"), visible_gpus=1) == torch.device("cuda", 0)
    assert processes.device(torch.device("cpu"), visible_gpus=1) == torch.device("cpu")


def test_one_process_sums_broadcasts_and_wraps_as_the_identity():
    alone = Processes()
    local = torch.tensor([2.5, 4.0], dtype=torch.float64)
    total = alone.sum(local)
    assert torch.equal(total, local)
    total += 1
    assert local.tolist() == [2.5, 4.0], "the sum is a copy: the caller's tensor is untouched"
    value = {"step": 3}
    assert alone.broadcast(value) is value
    alone.barrier()  # no process group: returns at once
    module = nn.Linear(2, 2)
    assert alone.wrap(module, torch.device("cpu")) is module
