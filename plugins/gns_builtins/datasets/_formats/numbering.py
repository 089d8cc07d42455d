"""The numbers trajectories are stored under in layouts that number them (DeepMind's ``key``, LagrangeBench's
groups)."""

from __future__ import annotations

from collections.abc import Sequence

from gns_framework.api import Trajectory


def trajectory_numbers(trajectories: Sequence[Trajectory]) -> list[int]:
    """Each trajectory's own name when every name in the split is a distinct decimal number,
    else its place in the split (0, 1, ...).

    A trajectory read from a numbered layout is named by its number, so converting
    keeps it: test trajectory 1 stays 1, not 0 because it comes first.
    """
    keys = [traj.key for traj in trajectories]
    if all(key.isascii() and key.isdecimal() for key in keys) and len({int(key) for key in keys}) == len(keys):
        return [int(key) for key in keys]
    return list(range(len(keys)))
