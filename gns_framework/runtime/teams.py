"""Teams: a job cut into groups of consecutive ranks, each with its own process group.

A scene split into P pieces (``training.partitions``, ``gns rollout --partitions``) needs one
process per piece; with more processes than that, teams of P split their own scenes and the
teams work side by side (data-parallel training, scenes rolled out in turn).
"""

from __future__ import annotations

from dataclasses import replace

import torch.distributed as dist

from .processes import Processes


def team_of(processes: Processes, size: int) -> Processes:
    """This process's team when the job is cut into teams of ``size`` consecutive ranks.

    Every process of the job calls it at once (each team's group is made by all). Ranks
    ``t * size .. (t + 1) * size - 1`` form team t; the result's rank and world size are
    this process's place in its team, and its collectives stay inside the team.
    """
    if size < 1 or processes.world_size % size:
        raise ValueError(f"{processes.world_size} processes do not split into teams of {size}")
    if size == processes.world_size:
        return processes
    mine = None
    for first in range(0, processes.world_size, size):
        group = dist.new_group(list(range(first, first + size)))
        if first <= processes.rank < first + size:
            mine = group
    return replace(processes, rank=processes.rank % size, world_size=size, group=mine)
