"""Slabs of equal particle count, who owns a particle, and who needs it as halo (decomposition/slabs.py)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.decomposition.slabs import SlabPartition


def test_cuts_give_slabs_of_equal_particle_count_along_the_widest_spread():
    generator = torch.Generator().manual_seed(0)
    position = torch.rand(1000, 3, generator=generator) * torch.tensor([1.0, 3.0, 0.5])
    partition = SlabPartition.balanced(position, 4, depth=0.1)
    assert partition.axis == 1 and partition.parts == 4 and partition.box is None
    assert torch.bincount(partition.owner(position), minlength=4).tolist() == [250] * 4


def test_a_periodic_axis_counts_its_box_length_and_closes_the_end_slabs():
    position = torch.tensor([[0.1, 0.2], [0.5, 0.3], [0.9, 0.25]])
    bounds = ((0.0, 1.0), (0.0, 1.0))
    # The particles spread over 0.8 in x and 0.1 in y, but y wraps around a box of length 1: y is widest.
    partition = SlabPartition.balanced(position, 2, depth=0.1, periodic_dims=(1,), bounds=bounds)
    assert partition.axis == 1 and partition.box == (0.0, 1.0)


def test_owners_at_and_beyond_the_cuts():
    partition = SlabPartition(axis=0, cuts=(0.25, 0.5, 0.75), depth=0.1)
    x = torch.tensor([-5.0, 0.0, 0.25, 0.4999, 0.5, 0.75, 7.0])
    position = torch.stack([x, torch.zeros_like(x)], dim=1)
    # A particle on a cut belongs to the slab above it; the end slabs are open.
    assert partition.owner(position).tolist() == [0, 0, 1, 1, 2, 3, 3]


def test_the_halo_is_every_slab_within_depth_but_the_own():
    partition = SlabPartition(axis=0, cuts=(0.25, 0.5, 0.75), depth=0.1)
    x = torch.tensor([0.15, 0.149, 0.3, 0.55, 0.0])
    halo = partition.halo_of(torch.stack([x, torch.zeros_like(x)], dim=1))
    assert halo.tolist() == [
        [False, True, False, False],  # 0.15: 0.10 below slab 1, just within
        [False, False, False, False],  # 0.149: 0.101 below slab 1
        [True, False, False, False],  # 0.3: 0.05 above slab 0, 0.2 below slab 2
        [False, True, False, False],  # 0.55: 0.05 above slab 1, 0.2 below slab 3
        [False, False, False, False],  # 0.0: 0.25 below slab 1
    ]


def test_a_slab_thinner_than_the_halo_sends_to_several_slabs():
    partition = SlabPartition(axis=0, cuts=(0.25, 0.3, 0.35), depth=0.2)
    halo = partition.halo_of(torch.tensor([[0.1, 0.0]]))
    assert halo.tolist() == [[False, True, True, False]]


def test_through_a_periodic_face_the_first_slab_needs_the_last_one():
    partition = SlabPartition(axis=0, cuts=(0.5,), depth=0.1, box=(0.0, 1.0))
    position = torch.tensor([[0.95, 0.5], [0.05, 0.5], [0.7, 0.5]])
    assert partition.halo_of(position).tolist() == [[True, False], [False, True], [False, False]]
    # Without the wrap-around neither end particle is near the other slab.
    open_ended = SlabPartition(axis=0, cuts=(0.5,), depth=0.1)
    assert not open_ended.halo_of(position).any()


def test_fewer_than_one_partition_is_refused():
    with pytest.raises(ValueError, match="partitions must be at least 1, got 0"):
        SlabPartition.balanced(torch.zeros(3, 2), 0, depth=0.1)
