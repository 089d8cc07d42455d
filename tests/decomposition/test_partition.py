"""Choosing the cut: slabs or blocks, whichever leaves the smaller halo (decomposition/partition.py)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.decomposition.blocks import BlockPartition
from gns_framework.decomposition.partition import balanced_partition, halo_count
from gns_framework.decomposition.slabs import SlabPartition


def _cloud(scale: tuple[float, float], n: int = 8000) -> torch.Tensor:
    return torch.rand(n, 2, generator=torch.Generator().manual_seed(0)) * torch.tensor(scale)


def _halo(partition, position) -> int:
    return int(partition.halo_of(position).sum())


def test_auto_takes_blocks_in_a_square_and_slabs_in_a_long_strip():
    square = _cloud((1.0, 1.0))
    chosen = balanced_partition(square, 8, 0.02)
    assert isinstance(chosen, BlockPartition)
    assert _halo(chosen, square) < _halo(SlabPartition.balanced(square, 8, 0.02), square)
    strip = _cloud((16.0, 1.0))
    chosen = balanced_partition(strip, 4, 0.02)
    assert isinstance(chosen, SlabPartition) and chosen.axis == 0
    assert _halo(chosen, strip) <= _halo(BlockPartition.balanced(strip, 4, 0.02), strip)


def test_two_pieces_an_axis_or_slabs_asked_for_give_slabs():
    square = _cloud((1.0, 1.0))
    assert isinstance(balanced_partition(square, 2, 0.02), SlabPartition)
    assert balanced_partition(square, 8, 0.02, axis=1).describe() == "8 slabs along dimension 1"
    assert isinstance(balanced_partition(square, 8, 0.02, "slabs"), SlabPartition)
    assert balanced_partition(square, 8, 0.02, "blocks").describe() == "8 blocks (recursive bisection)"


def test_the_halo_counted_in_chunks_is_the_whole_count():
    square = _cloud((1.0, 1.0))
    for cut in ("slabs", "blocks"):
        partition = balanced_partition(square, 8, 0.02, cut)
        assert halo_count(partition, square, chunk=777) == _halo(partition, square) > 0


def test_blocks_with_an_axis_are_refused():
    with pytest.raises(ValueError, match="a cut into blocks has no single axis, got axis 0"):
        balanced_partition(_cloud((1.0, 1.0)), 4, 0.02, "blocks", axis=0)
