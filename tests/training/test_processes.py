"""A process's place in the job: which GPU it takes, collectives that are the identity for one process, and teams.

The collectives across real processes are tested under torchrun in test_distributed.py; a team's here.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from spawned import free_loopback_port, run_processes
from torch import nn

from gns_framework.training.processes import Processes


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


def test_teams_must_divide_the_job_and_one_team_is_the_job():
    job = Processes(rank=3, world_size=4)
    assert job.teams(4) is job
    with pytest.raises(ValueError, match="4 processes do not split into teams of 3"):
        job.teams(3)


def _team_sums(rank: int, world: int, port: int, out: str) -> None:
    """Rank r of 4 in teams of 2: its place in its team, the team's sum of r, its broadcast from the team's first."""
    import os

    from gns_framework.training import distributed

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), GLOO_SOCKET_IFNAME="lo")
    job = Processes(rank, world)
    distributed.start(job, torch.device("cpu"))
    try:
        team = job.teams(2)
        summed = int(team.sum(torch.tensor(rank)))
        everyone = int(job.sum(torch.tensor(rank)))
        first = team.broadcast(f"from {rank}")
        torch.save(
            {"rank": team.rank, "size": team.world_size, "sum": summed, "all": everyone, "first": first},
            Path(out) / f"rank{rank}.pt",
        )
    finally:
        distributed.stop()


def test_a_team_sums_and_broadcasts_among_its_own_processes(tmp_path):
    run_processes(_team_sums, (4, free_loopback_port(), str(tmp_path)), 4)
    got = [torch.load(tmp_path / f"rank{rank}.pt", weights_only=True) for rank in range(4)]
    assert [(g["rank"], g["size"]) for g in got] == [(0, 2), (1, 2), (0, 2), (1, 2)]
    assert [g["sum"] for g in got] == [1, 1, 5, 5] and all(g["all"] == 6 for g in got)
    assert [g["first"] for g in got] == ["from 0", "from 0", "from 2", "from 2"]
