"""Buffers sized once per scene (_kernels/fixed_capacity.py): sized on a scene's first search, grown when a check
finds them short (pairs, candidates, grid), sized anew for another scene, searches in between without read-backs."""

from __future__ import annotations

import math

import torch

from gns_builtins._kernels.cell_list import radius_pairs
from gns_builtins._kernels.fixed_capacity import FixedCapacityRadius
from gns_framework.runtime.sync_counter import SyncCounter


def _cloud(n, seed=0, scale=1.0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=generator) * scale, torch.zeros(n, dtype=torch.long)


def test_the_first_search_sizes_the_buffers_with_room_to_grow():
    position, batch = _cloud(400)
    search = FixedCapacityRadius(0.08, growth=1.25)
    senders, _ = search.pairs(position, batch, 1, check_now=False)
    exact = radius_pairs(position, batch, 0.08)[0].numel()
    assert search.sizings == 1 and search.edge_capacity == senders.numel() == math.ceil(1.25 * exact)
    assert search.candidate_capacity > search.edge_capacity  # candidates: every particle of the 3x3 cells


def test_searches_of_the_same_scene_read_nothing_back_until_the_check():
    position, batch = _cloud(400)
    search = FixedCapacityRadius(0.08, growth=1.25)
    search.pairs(position, batch, 1, check_now=False)
    with SyncCounter() as counter:
        for k in range(4):
            search.pairs(position * (1 - 0.01 * k), batch, 1, check_now=False)
    assert counter.counts == {}
    assert not search.overflowed() and search.sizings == 1


def test_another_scene_is_sized_anew():
    search = FixedCapacityRadius(0.08, growth=1.25)
    search.pairs(*_cloud(400), 1, check_now=False)
    small = search.edge_capacity
    search.pairs(*_cloud(900, seed=1), 1, check_now=False)
    assert search.sizings == 2 and search.edge_capacity > 2 * small


def test_a_scene_that_spreads_grows_the_grid_and_keeps_its_pairs():
    position, batch = _cloud(300)
    search = FixedCapacityRadius(0.05, growth=1.25)
    search.pairs(position, batch, 1, check_now=False)
    spread = position * 3.0  # three times the extent: beyond the grid, the last cells collect the rest
    for _ in range(3):
        senders, receivers = search.pairs(spread, batch, 1, check_now=False)
        if not search.overflowed():
            break
    exact_senders, exact_receivers = radius_pairs(spread, batch, 0.05)
    count = exact_senders.numel()
    assert torch.equal(senders[:count], exact_senders) and torch.equal(receivers[:count], exact_receivers)
    # The grid now covers the spread scene, within its cap of cells per particle (larger cells instead).
    grid = search.grid
    assert min(grid.cells_per_axis) * grid.cell > 2.9 and grid.num_cells <= 1.1 * 4 * 300


def test_a_short_buffer_checked_at_once_is_searched_again():
    position, batch = _cloud(400)
    search = FixedCapacityRadius(0.08, growth=1.0)
    search.pairs(position, batch, 1, check_now=True)
    denser = 0.5 + 0.7 * (position - 0.5)
    senders, receivers = search.pairs(denser, batch, 1, check_now=True)
    exact_senders, exact_receivers = radius_pairs(denser, batch, 0.08)
    count = exact_senders.numel()
    assert torch.equal(senders[:count], exact_senders) and torch.equal(receivers[:count], exact_receivers)
    assert search.sizings >= 2
