"""Blocks by recursive bisection: balanced counts, owners that tile space, and a halo that covers the receptive field
(decomposition/blocks.py)."""

from __future__ import annotations

import itertools

import pytest
import torch

from gns_framework.decomposition.blocks import BlockPartition
from gns_framework.decomposition.slabs import SlabPartition


def _cloud(n: int, scale: tuple[float, ...], seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(n, len(scale), generator=generator, dtype=torch.float64) * torch.tensor(scale)


@pytest.mark.parametrize("parts", [2, 3, 4, 5, 8])
@pytest.mark.parametrize("scale", [(1.0, 1.0), (1.0, 0.6, 0.8)])
def test_every_block_gets_its_share_of_the_particles_and_every_particle_one_owner(parts, scale):
    position = _cloud(1200, scale)
    partition = BlockPartition.balanced(position, parts, depth=0.05)
    assert partition.parts == parts
    counts = torch.bincount(partition.owner(position), minlength=parts)
    assert counts.sum() == 1200 and (counts - 1200 / parts).abs().max() <= 1, counts
    # The boxes tile space: points anywhere, outside the cloud too, are each inside exactly one box.
    anywhere = _cloud(500, scale, seed=1) * 3 - 1
    lower = torch.tensor(partition.lower)
    upper = torch.tensor(partition.upper)
    inside = ((anywhere[:, None] >= lower) & (anywhere[:, None] < upper)).all(-1)
    assert (inside.sum(1) == 1).all()
    assert torch.equal(inside.to(torch.uint8).argmax(1), partition.owner(anywhere))


def test_a_square_is_cut_into_quarters_and_a_long_strip_into_slabs():
    square = BlockPartition.balanced(_cloud(4000, (1.0, 1.0)), 4, depth=0.05)
    for lower, upper in zip(square.lower, square.upper, strict=True):
        finite = [bound for bound in lower + upper if abs(bound) != float("inf")]
        assert len(finite) == 2 and all(abs(bound - 0.5) < 0.05 for bound in finite), (lower, upper)
    strip = BlockPartition.balanced(_cloud(4000, (8.0, 1.0)), 4, depth=0.05)
    assert all(
        lower[1] == -float("inf") and upper[1] == float("inf")
        for lower, upper in zip(strip.lower, strip.upper, strict=True)
    )


def _min_image_distance(a: torch.Tensor, b: torch.Tensor, box: tuple) -> torch.Tensor:
    """(N, M) Euclidean distances, through periodic faces where ``box`` has them."""
    difference = (a[:, None] - b[None]).abs()
    for k, wrap in enumerate(box):
        if wrap is not None:
            length = wrap[1] - wrap[0]
            difference[..., k] = torch.minimum(difference[..., k], length - difference[..., k])
    return difference.norm(dim=-1)


@pytest.mark.parametrize("periodic", [(), (0,), (0, 1)])
@pytest.mark.parametrize("parts", [3, 4, 6])
def test_the_halo_holds_every_particle_within_depth_of_an_owned_one_and_no_particle_farther_than_depth(periodic, parts):
    """The invariant a decomposition rests on, checked pair by pair; and the halo is no deeper than it must be."""
    position = _cloud(600, (1.0, 1.0), seed=2)
    depth = 0.12
    bounds = ((0.0, 1.0), (0.0, 1.0))
    partition = BlockPartition.balanced(position, parts, depth, periodic_dims=periodic, bounds=bounds)
    owner, halo = partition.owner(position), partition.halo_of(position)
    near = _min_image_distance(position, position, partition.box) <= depth
    for r in range(parts):
        mine = owner == r
        needed = near[mine].any(0) & ~mine
        assert not (needed & ~halo[:, r]).any(), f"block {r} misses a particle within depth of one it owns"
        assert not (halo[:, r] & mine).any()
    # Brute force on each box: clamp a particle (and its periodic images) into the box; halo iff within depth.
    lower, upper = torch.tensor(partition.lower), torch.tensor(partition.upper)
    for k in periodic:
        lower[:, k], upper[:, k] = lower[:, k].clamp(min=0.0), upper[:, k].clamp(max=1.0)
    shifts = [
        torch.tensor(s, dtype=torch.float64)
        for s in itertools.product(*[(-1, 0, 1) if k in periodic else (0,) for k in range(2)])
    ]
    gap = torch.stack(
        [(position + s - (position + s).clamp(lower[:, None], upper[:, None])).norm(dim=-1) for s in shifts]
    )
    within = depth >= gap.min(0).values.T
    within[torch.arange(600), owner] = False
    assert torch.equal(within, halo)


def test_blocks_leave_a_smaller_halo_than_slabs_in_a_square_at_many_processes():
    position = _cloud(20000, (1.0, 1.0), seed=3)
    depth = 0.02
    for parts in (4, 8, 16):
        blocks = BlockPartition.balanced(position, parts, depth).halo_of(position).sum()
        slabs = SlabPartition.balanced(position, parts, depth).halo_of(position).sum()
        assert blocks < slabs, parts


def test_fewer_particles_than_blocks_still_tile_space():
    position = torch.tensor([[0.2, 0.3], [0.7, 0.1]], dtype=torch.float64)
    partition = BlockPartition.balanced(position, 4, depth=0.1)
    assert partition.parts == 4
    owner = partition.owner(position)
    assert owner.unique().numel() == 2
    assert partition.halo_of(position).shape == (2, 4)


def test_fewer_than_one_block_is_refused():
    with pytest.raises(ValueError, match="partitions must be at least 1, got 0"):
        BlockPartition.balanced(torch.zeros(3, 2), 0, depth=0.1)


def test_owners_and_halo_taken_in_chunks_are_those_taken_at_once(monkeypatch):
    from gns_framework.decomposition import blocks

    position = _cloud(3000, (1.0, 0.5, 0.7), seed=4)
    partition = BlockPartition.balanced(position, 6, depth=0.08, periodic_dims=(1,), bounds=((0, 1),) * 3)
    whole = partition.owner(position), partition.halo_of(position)
    monkeypatch.setattr(blocks, "CHUNK", 113)
    assert torch.equal(partition.owner(position), whole[0])
    assert torch.equal(partition.halo_of(position), whole[1])
    assert partition.owner(position[:0]).shape == (0,) and partition.halo_of(position[:0]).shape == (0, 6)
