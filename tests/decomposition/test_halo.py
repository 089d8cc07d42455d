"""The receptive field a halo must cover, and the halo each process fetches (decomposition/halo.py)."""

from __future__ import annotations

import pytest
import torch
from decomposition_cases import CASES, case_simulator, case_trajectory, halo_worker
from spawned import free_loopback_port, run_processes
from tiny import TINY_GRAPH_BUILDERS, TINY_PROCESSORS

from gns_framework.data.batch import window
from gns_framework.decomposition.halo import halo_depth, halo_kind, receptive_field, with_halo
from gns_framework.decomposition.particles import Particles
from gns_framework.decomposition.slabs import SlabPartition
from gns_framework.errors import GnsError
from gns_framework.plugins import load_registry


def test_the_built_in_components_declare_their_reach():
    registry = load_registry()
    builders = {e.name: e.cls.joins_within_radius for e in registry.entries("graph_builder")}
    assert {name: builders[name] for name in TINY_GRAPH_BUILDERS} == {
        "radius": True,
        "radius_fixed_capacity": True,  # the same edges, padded
        "periodic_radius": True,
        "radius_torch_cluster": True,
        "knn": False,  # its edges depend on which other particles are near
        "no_edges": False,  # a grid processor's grid spans the scene: no piece holds what it needs
    }
    processors = {e.name: (e.cls.hops_param, e.cls.exchanges_latents) for e in registry.entries("processor")}
    steps = "message_passing_steps"
    assert {name: processors[name] for name in TINY_PROCESSORS} == {
        "interaction_network": (steps, True),
        "shared_interaction_network": (steps, True),
        "graph_attention": (steps, False),
        "egnn": (steps, False),
        "grid_cnn": (None, False),  # its grid spans the scene
    }


def test_the_receptive_field_is_the_connectivity_radius_times_the_message_passing_steps():
    for name, (*_, radius) in CASES.items():
        assert receptive_field(case_simulator(name)) == pytest.approx(2 * radius)


def test_a_builder_or_processor_without_a_bounded_reach_is_refused_naming_both(monkeypatch):
    from gns_builtins.graph_builders.knn import KnnGraphBuilder

    simulator = case_simulator("2d_walls")
    simulator.graph_builder = KnnGraphBuilder(KnnGraphBuilder.Params(k=6), simulator.setup)
    # As a grid over the whole scene would: no bound on how far a particle's output reaches.
    monkeypatch.setattr(type(simulator.processor), "hops_param", None)
    with pytest.raises(GnsError) as refused:
        receptive_field(simulator)
    assert "graph builder 'knn' joins particles by more than their own distance" in str(refused.value)
    assert "processor 'interaction_network' does not bound how far" in str(refused.value)


def test_alone_the_local_particles_are_the_owned_ones_sorted_by_id():
    owned = Particles(torch.tensor([5, 1, 3]), torch.arange(3.0)[:, None, None].expand(3, 2, 2), torch.zeros(3))
    particles = with_halo(owned, SlabPartition(axis=0, cuts=(), depth=1.0), world=1)
    local, owned_rows = particles.local, particles.owned_rows
    assert local.ids.tolist() == [1, 3, 5] and particles.halo_count == 0
    assert torch.equal(local.ids[owned_rows], owned.ids)
    assert torch.equal(local.sequence[owned_rows], owned.sequence)
    latent = torch.randn(3, 4)
    assert torch.equal(particles.refresh(latent), latent)  # no halo: nothing to refresh


def test_the_halo_kind_follows_the_processor_and_latents_are_refused_where_it_does_not_exchange(monkeypatch):
    simulator = case_simulator("2d_walls")
    assert halo_kind(simulator, "auto") == "latents" and halo_kind(simulator, "positions") == "positions"
    assert halo_depth(simulator, "latents") == pytest.approx(0.1) and halo_depth(
        simulator, "positions"
    ) == pytest.approx(0.2)
    monkeypatch.setattr(type(simulator.processor), "exchanges_latents", False)
    assert halo_kind(simulator, "auto") == "positions"
    with pytest.raises(GnsError, match="does not exchange node latents between its message-passing steps"):
        halo_kind(simulator, "latents")


def test_each_process_gets_exactly_the_particles_within_the_receptive_field_of_its_slab(tmp_path):
    world = 3
    run_processes(halo_worker, (world, free_loopback_port(), str(tmp_path)), world, seconds=120)
    start = window(case_trajectory("2d_walls"), 0, 6, with_target=False)
    last = start.position_sequence[:, -1]
    depth = receptive_field(case_simulator("2d_walls"))
    partition = SlabPartition.balanced(last, world, depth)
    x = last[:, partition.axis].double()
    lower = [float("-inf"), *partition.cuts]
    upper = [*partition.cuts, float("inf")]
    for rank in range(world):
        got = torch.load(tmp_path / f"rank{rank}.pt", weights_only=True)
        mine = (x >= lower[rank]) & (x < upper[rank])
        # Brute force: every other particle within the depth of the slab along x.
        near = ~mine & (x >= lower[rank] - depth) & (x <= upper[rank] + depth)
        assert sorted(got["owned"].tolist()) == mine.nonzero()[:, 0].tolist()
        assert got["local"].tolist() == (mine | near).nonzero()[:, 0].tolist()
        assert got["halo"] == int(near.sum()) > 0
        assert torch.equal(got["local"][got["owned_rows"]], got["owned"])
        assert torch.equal(got["local_sequence"], start.position_sequence[got["local"]])
        # The latent exchange gave every halo row its owner's value.
        assert got["refreshed"][:, 0].tolist() == got["local"].double().tolist()
