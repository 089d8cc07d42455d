"""How a scene is cut into one piece per process: slabs or blocks, whichever leaves the smaller halo.

Both cuts balance the work (each particle weighing one plus the edges it receives, :mod:`.work`), or the
particle count; they differ in the halo. A slab's halo is two faces
as large as the domain's cross-section, whatever P; a block's shrinks as P grows. Which is
smaller depends on the scene's shape and P, and costs one pass over the particles to
count, so ``auto`` counts both and takes the smaller (slabs on a tie: at P = 2 they are the
same cut).
"""

from __future__ import annotations

from typing import Literal, Protocol, Unpack

from torch import Tensor

from .blocks import BlockPartition
from .slabs import SlabPartition
from .space import CutOptions

Cut = Literal["auto", "slabs", "blocks"]


class Partition(Protocol):
    """One piece of space per process: who owns a particle, and which processes need it as halo."""

    @property
    def depth(self) -> float:
        """Halo depth (dataset length units)."""
        ...

    @property
    def parts(self) -> int: ...

    def owner(self, position: Tensor) -> Tensor:
        """(N,) int64 process owning each position (N, d)."""
        ...

    def halo_of(self, position: Tensor) -> Tensor:
        """(N, P) bool: whether process r needs particle i as halo (never its owner)."""
        ...

    def describe(self) -> str:
        """The cut in words, e.g. ``4 slabs along dimension 0``."""
        ...


def balanced_partition(
    position: Tensor,
    parts: int,
    depth: float,
    cut: Cut = "auto",
    axis: int | None = None,
    **options: Unpack[CutOptions],
) -> Partition:
    """``parts`` pieces of equal weight (:class:`~.space.CutOptions`; default: equal particle count) of the scene
    at ``position`` (N, d), cut as ``cut`` says.

    ``axis`` fixes the dimension slabs are cut across (so ``auto`` means slabs).
    """
    if cut == "blocks" and axis is not None:
        raise ValueError(f"a cut into blocks has no single axis, got axis {axis}: use slabs or leave the axis out")
    slabs = blocks = None
    if cut != "blocks":
        slabs = SlabPartition.balanced(position, parts, depth, axis, **options)
    if cut == "blocks" or (cut == "auto" and axis is None and parts > 2):
        blocks = BlockPartition.balanced(position, parts, depth, **options)
    if slabs is None:
        assert blocks is not None
        return blocks
    if blocks is None or halo_count(slabs, position) <= halo_count(blocks, position):
        return slabs
    return blocks


def halo_count(partition: Partition, position: Tensor, chunk: int = 65_536) -> int:
    """Halo copies ``partition`` makes of the particles at ``position`` (N, d): a particle counts once per process
    that needs it. Counted ``chunk`` particles at a time, so that N x P distances never sit in memory at once."""
    return sum(int(partition.halo_of(rows).sum()) for rows in position.split(chunk))
