"""The radius search into fixed-size buffers (_kernels/padded_cell_list.py): the same pairs in the same order as
the exact search, padding after them, an overflow flag when a buffer is too small, and no wait for the device."""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels.cell_list import radius_pairs
from gns_builtins._kernels.padded_cell_list import CellGrid, padded_radius_pairs
from gns_framework.runtime.sync_counter import SyncCounter


def _scene(n: int, dim: int, examples: int = 1, seed: int = 0, spread: float = 1.0):
    generator = torch.Generator().manual_seed(seed)
    position = torch.rand(n, dim, generator=generator) * spread
    batch = torch.sort(torch.randint(0, examples, (n,), generator=generator)).values
    return position, batch


def _search(position, batch, examples, radius, extent, candidates=1 << 16, edges=1 << 15, pad=None):
    """The search with a grid covering ``extent``; returns senders, receivers, count, overflow."""
    grid = CellGrid.for_extent(extent, radius, max_cells=1 << 20)
    found = padded_radius_pairs(position, batch, examples, radius, grid, candidates, edges, pad=pad)
    return found.senders, found.receivers, found.pairs, found.overflowed(candidates, edges)


@pytest.mark.parametrize("dim, examples", [(2, 1), (2, 3), (3, 1), (3, 2)])
def test_the_first_count_rows_are_the_exact_search_in_its_order(dim, examples):
    position, batch = _scene(400 if dim == 2 else 300, dim, examples)
    radius = 0.12
    senders, receivers, count, overflow = _search(position, batch, examples, radius, (1.0,) * dim)
    exact_senders, exact_receivers = radius_pairs(position, batch, radius)
    count = int(count)
    assert not overflow and count == exact_senders.numel() > 400
    assert torch.equal(senders[:count], exact_senders) and torch.equal(receivers[:count], exact_receivers)
    last = position.shape[0] - 1
    assert (senders[count:] == last).all() and (receivers[count:] == last).all()  # padding keeps receivers sorted
    assert (receivers[1:] >= receivers[:-1]).all()


def test_particles_beyond_the_walls_lose_no_pair():
    # A third of the particles far outside the bounds (one at 1e30): the margin cells collect them.
    position, batch = _scene(300, 2, seed=3, spread=1.0)
    position[:100] = position[:100] * 0.2 - 0.5  # a cluster left of and below the box
    position[100] = torch.tensor([1e30, 0.5])
    position[101] = torch.tensor([1.0e30, 0.5])  # its neighbour, far beyond the wall
    radius = 0.08
    senders, receivers, count, overflow = _search(position, batch, 1, radius, (1.0, 1.0))
    exact_senders, exact_receivers = radius_pairs(position, batch, radius)
    assert not overflow and torch.equal(senders[: int(count)], exact_senders)
    assert torch.equal(receivers[: int(count)], exact_receivers)


@pytest.mark.parametrize("short", ["candidates", "edges"])
def test_a_buffer_too_small_raises_the_overflow_flag(short):
    position, batch = _scene(400, 2)
    exact = radius_pairs(position, batch, 0.12)[0].numel()
    sizes = {"candidates": 1 << 16, "edges": 1 << 15, short: exact - 1}
    _, _, count, overflow = _search(position, batch, 1, 0.12, (1.0,) * 2, sizes["candidates"], sizes["edges"])
    assert bool(overflow)
    _, _, count, overflow = _search(position, batch, 1, 0.12, (1.0,) * 2, 1 << 16, exact)
    assert not overflow and int(count) == exact  # exactly full is not an overflow


def test_the_search_never_waits_for_the_device():
    position, batch = _scene(500, 3, examples=2)
    with SyncCounter() as counter:
        _search(position, batch, 2, 0.15, (1.0,) * 3)
    assert counter.counts == {}
    with SyncCounter() as counter:
        radius_pairs(position, batch, 0.15)
    assert counter.total > 0  # the exact search does: the counter sees it


def test_a_grid_covers_the_extent_with_a_margin_cell_each_side():
    grid = CellGrid.for_extent((1.0, 0.5), 0.1, max_cells=1000)
    assert grid.cells_per_axis == (12, 7) and grid.num_cells == 84
    lower = torch.tensor([-0.1, -0.1], dtype=torch.float64)
    points = torch.tensor(
        [[-3.0, 0.05], [0.55, 9.0], [float("inf"), -1e300], [float("nan"), 0.0]]
    )  # 0.1 m above lower: still cell 0 (cells are a hair over R)
    assert grid.coordinates(points, lower).tolist() == [[0, 1], [6, 6], [11, 0], [0, 0]]


def test_a_spread_scene_gets_larger_cells_not_more_of_them():
    grid = CellGrid.for_extent((100.0, 100.0), 0.1, max_cells=10_000)
    assert grid.num_cells <= 10_000 * 1.1 and grid.cell > 0.1


def test_the_grid_follows_the_particles():
    # The same cloud moved 50 m away: the grid starts at its lowest corner, so the pairs are the same.
    position, batch = _scene(300, 2, seed=5)
    near = _search(position, batch, 1, 0.1, (1.0, 1.0))
    far = _search(position + 50.0, batch, 1, 0.1, (1.0, 1.0))
    assert int(far[2]) == int(near[2]) and torch.equal(far[0], near[0]) and torch.equal(far[1], near[1])


def test_padding_may_name_a_sink_beyond_the_particles():
    position, batch = _scene(200, 2, seed=1)
    senders, receivers, count, _ = _search(position, batch, 1, 0.1, (1.0, 1.0), edges=1 << 13, pad=200)
    assert (senders[int(count) :] == 200).all() and (receivers[int(count) :] == 200).all()
    assert (receivers[1:] >= receivers[:-1]).all()


def test_no_particles_give_padding_only():
    senders, _receivers, count, overflow = _search(
        torch.zeros(0, 2), torch.zeros(0, dtype=torch.long), 1, 0.1, (1.0,) * 2, 8, 4
    )
    assert senders.shape == (4,) and int(count) == 0 and not overflow


def test_non_finite_particles_join_no_pair_and_cost_no_candidates():
    # A capacity class pads a batch with NaN rows (model/capacity_classes.py): all in one place, they would
    # otherwise examine each other, (padding)^2 candidates for no pair.
    position, batch = _scene(200, 2, seed=2)
    alone = padded_radius_pairs(
        position, batch, 1, 0.1, CellGrid.for_extent((1.0, 1.0), 0.1, 1 << 20), 1 << 14, 1 << 13
    )
    padded = torch.cat([position, torch.full((300, 2), float("nan")), torch.tensor([[float("inf"), 0.5]])])
    grid = CellGrid.for_extent((1.0, 1.0), 0.1, 1 << 20)
    found = padded_radius_pairs(padded, torch.zeros(501, dtype=torch.long), 1, 0.1, grid, 1 << 14, 1 << 13, pad=200)
    count = int(found.pairs)
    assert count == int(alone.pairs) > 200 and int(found.candidates) == int(alone.candidates)
    assert torch.equal(found.senders[:count], alone.senders[:count])
    assert torch.equal(found.receivers[:count], alone.receivers[:count])
