"""Pieces cut by work (decomposition/work.py): each particle one plus the edges it receives; a dense pile beside
loose spray gets pieces of equal work, not of equal particle count."""

from __future__ import annotations

import pytest
import torch

from gns_builtins.graph_builders.no_edges import NoEdgesGraphBuilder
from gns_builtins.graph_builders.radius import RadiusGraphBuilder
from gns_builtins.graph_builders.radius_fixed_capacity import FixedCapacityRadiusGraphBuilder
from gns_framework.contracts import ModelSetup
from gns_framework.decomposition.partition import balanced_partition
from gns_framework.decomposition.work import particle_work, quantile_cut

SETUP = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.05, particle_types=(6,))


def _pile_and_spray(seed: int = 0) -> torch.Tensor:
    """600 particles packed in the left tenth of the box, 600 spread over the rest: 8x the neighbours on the left."""
    generator = torch.Generator().manual_seed(seed)
    pile = torch.rand(600, 2, generator=generator) * torch.tensor([0.1, 0.5])
    spray = torch.rand(600, 2, generator=generator) * torch.tensor([0.9, 0.5]) + torch.tensor([0.1, 0.0])
    return torch.cat([pile, spray]).double()


def test_a_cut_by_count_is_the_unweighted_quantile():
    coordinate = torch.tensor([0.5, 0.1, 0.9, 0.3, 0.7])
    assert quantile_cut(coordinate, None, 1, 2) == float(torch.sort(coordinate).values[2])
    for below, parts in ((1, 2), (1, 3), (2, 3), (3, 4)):
        assert quantile_cut(coordinate, torch.ones(5), below, parts) == quantile_cut(coordinate, None, below, parts)
    # The particle at 0.9 weighs 4 of 8: half the weight lies below it, and the cut moves there from 0.5.
    assert quantile_cut(coordinate, torch.tensor([1.0, 1.0, 4.0, 1.0, 1.0]), 1, 2) == float(torch.tensor(0.9))


def test_work_is_one_plus_the_edges_received_and_padding_is_no_work():
    position = _pile_and_spray()
    radius = RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP)
    graph = radius.build(position, torch.zeros(len(position), dtype=torch.long), 1)
    expected = 1.0 + torch.bincount(graph.receivers, minlength=len(position)).double()
    assert torch.equal(particle_work(radius, position), expected)
    fixed = FixedCapacityRadiusGraphBuilder(FixedCapacityRadiusGraphBuilder.Params(), SETUP)
    assert torch.equal(particle_work(fixed, position), expected), "the sink node's padding is nobody's work"
    assert torch.equal(
        particle_work(NoEdgesGraphBuilder(NoEdgesGraphBuilder.Params(), SETUP), position),
        torch.ones(1200, dtype=torch.float64),
    )


def test_pieces_cut_by_work_receive_about_equal_edges_where_pieces_by_count_do_not():
    position = _pile_and_spray()
    work = particle_work(RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP), position)

    def piece_work(partition) -> torch.Tensor:
        owner = partition.owner(position)
        return torch.stack([work[owner == r].sum() for r in range(4)])

    for cut in ("slabs", "blocks"):
        by_count = piece_work(balanced_partition(position, 4, 0.1, cut))
        by_work = piece_work(balanced_partition(position, 4, 0.1, cut, weight=work))
        assert by_count.max() / by_count.min() > 3, (cut, by_count)  # the pile's pieces carry most of the edges
        assert by_work.max() / by_work.min() < 1.25, (cut, by_work)


def test_a_partitioned_rollout_cuts_its_pieces_by_the_models_work():
    # partition_for, as the partitioned rollout and training call it, weighs the particles by the model's own graph.
    from decomposition_cases import case_simulator

    from gns_framework.decomposition.halo import partition_for

    simulator = case_simulator("2d_walls")  # R = 0.1: the pile's particles have ~8x the spray's neighbours
    position = _pile_and_spray().float()
    partition, _ = partition_for(simulator, position, 4, "latents", cut="slabs")
    work = particle_work(simulator.graph_builder, position)
    owner = partition.owner(position)
    shares = torch.stack([work[owner == r].sum() for r in range(4)])
    assert shares.max() / shares.min() < 1.25, shares


def test_the_work_summary_keeps_the_whole_work_and_cuts_pieces_balanced_to_within_a_slice_of_cells():
    """The pile and spray binned on the summary's grid: the same total work, and pieces cut from the occupied cells
    hold the particles' work in equal shares up to what one slice of cells holds (a cut cannot split one);
    checked against the particles themselves."""
    from gns_framework.decomposition.work import work_summary
    from gns_framework.runtime.processes import Processes

    position = _pile_and_spray()
    work = particle_work(RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP), position)
    centres, cell_work, cell_count = work_summary(position, work, len(position), Processes())
    assert torch.isclose(cell_work.sum(), work.sum(), rtol=1e-12) and int(cell_count.sum()) == len(position)
    assert (cell_count >= 1).all() and len(centres) <= len(position)  # occupied cells only
    slices = [torch.unique(centres[:, axis], return_inverse=True)[1] for axis in range(2)]
    heaviest_slice = max(float(torch.bincount(s, weights=cell_work).max()) for s in slices) / float(work.sum())
    assert heaviest_slice < 0.05, "the grid must be fine enough for the bound below to mean something"
    for cut in ("slabs", "blocks"):
        pieces = balanced_partition(centres, 4, 0.05, cut, weight=cell_work)
        shares = torch.bincount(pieces.owner(position), weights=work, minlength=4) / work.sum()
        assert (shares - 0.25).abs().max() <= 2 * heaviest_slice, (cut, shares.tolist(), heaviest_slice)
        by_cells = balanced_partition(centres, 4, 0.05, cut)  # every occupied cell alike: not the work
        off = torch.bincount(by_cells.owner(position), weights=work, minlength=4) / work.sum()
        assert (off - 0.25).abs().max() > 4 * heaviest_slice, "the test needs cells unlike in work"


def _slowest_piece(partition, position: torch.Tensor, builder, kind: str) -> float:
    """The work of the busiest piece: its own particles and, computed beside them, its halo (with a halo of
    positions each halo particle with its edges, measured on the piece's own graph; of latents one node each)."""
    owner, halo = partition.owner(position), partition.halo_of(position)
    busiest = 0.0
    for r in range(partition.parts):
        own = owner == r
        local = own | halo[:, r]
        work = particle_work(builder, position[local])
        total = work.sum() if kind == "positions" else work[own[local]].sum() + (~own[local]).sum()
        busiest = max(busiest, float(total))
    return busiest


def test_a_cut_weighs_the_halo_it_makes():
    from gns_framework.decomposition.work import halo_cut

    coordinate = torch.arange(10, dtype=torch.float64)
    # Without halo work the middle; a side gets the 3 particles within depth 3 across the cut as its halo.
    halo = torch.zeros(10, dtype=torch.float64)
    assert halo_cut(coordinate, None, halo, 3.0, 1, 2) == quantile_cut(coordinate, None, 1, 2) == 5.0
    # Heavy halo on the right (particles 5-9 cost 10 each as halo): the left side, which holds some of them as
    # halo, keeps fewer particles of its own.
    heavy = torch.where(coordinate >= 5, 10.0, 0.0).double()
    assert halo_cut(coordinate, None, heavy, 3.0, 1, 2) < 5.0


@pytest.mark.parametrize("cut", ["slabs", "blocks"])
def test_pieces_that_weigh_their_halo_finish_sooner_with_a_deep_halo_of_positions(cut):
    """A deep halo of positions (depth 0.1, the pile's width): the pile's pieces compute most of it as halo.
    Weighing the halo each cut makes shortens the busiest piece's work, which sets the step's time."""
    position = _pile_and_spray()
    builder = RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP)
    work = particle_work(builder, position)
    own_only = balanced_partition(position, 4, 0.1, cut, weight=work)
    with_halo = balanced_partition(position, 4, 0.1, cut, weight=work, halo_weight=work)
    before = _slowest_piece(own_only, position, builder, "positions")
    after = _slowest_piece(with_halo, position, builder, "positions")
    assert after < 0.9 * before, (cut, before, after)
