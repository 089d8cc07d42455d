"""How much of a split a training process holds in memory (``dataset.memory``).

Under DDP every process used to read and keep the whole dataset, so host memory
grew with the number of processes times the dataset. In ``windows`` mode a process
keeps only the few trajectories it used last: its windows come from the same
global sample order as before (:class:`~.windows.WindowOrder`), so training is
bitwise the same, and a trajectory it needs again is read again (from the page
cache, which every process on a machine shares, or mapped from the file).
"""

from __future__ import annotations

TRAJECTORIES_KEPT = 8
"""Trajectories a process keeps in ``windows`` mode: a step's batch draws from a few of them."""


def trajectories_kept(memory: str, processes: int) -> int | None:
    """How many trajectories a split keeps (None: every one read) for ``dataset.memory`` and the process count."""
    if memory == "all" or (memory == "auto" and processes == 1):
        return None
    return TRAJECTORIES_KEPT
