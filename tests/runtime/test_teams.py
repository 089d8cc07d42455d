"""Teams of consecutive ranks, each with its own process group (runtime/teams.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from spawned import free_loopback_port, run_processes

from gns_framework.runtime.processes import Processes
from gns_framework.runtime.teams import team_of


def test_teams_must_divide_the_job_and_one_team_is_the_job():
    job = Processes(rank=3, world_size=4)
    assert team_of(job, 4) is job
    with pytest.raises(ValueError, match="4 processes do not split into teams of 3"):
        team_of(job, 3)


def _team_sums(rank: int, world: int, port: int, out: str) -> None:
    """Rank r of 4 in teams of 2: its place in its team, the team's sum of r, its broadcast from the team's first."""
    import os

    from gns_framework.training import distributed

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), GLOO_SOCKET_IFNAME="lo")
    job = Processes(rank, world)
    distributed.start(job, torch.device("cpu"))
    try:
        team = team_of(job, 2)
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
