"""The torch-cluster radius builder: its cap doubling and exact filter (on a stand-in search), and its error.

torch-cluster is optional and usually absent: the builder's own logic (retrying with a
doubled neighbour cap, filtering the widened search to the strict radius, sorting) is
tested with a brute-force stand-in for ``torch_cluster.radius``; the comparison with
the real library runs only where it is installed.
"""

from __future__ import annotations

import sys
import types

import pytest
import torch
from graph_cases import REGISTRY, build, edge_set, random_positions

from gns_framework.errors import PluginError
from gns_framework.testing import small_scene


def stand_in_torch_cluster(calls: list[int]) -> types.ModuleType:
    """A module whose ``radius`` behaves as torch-cluster's: (query, neighbour) rows, at most the cap per query.

    It includes pairs at distance <= r (not the builder's strict <) and keeps the first
    ``max_num_neighbors`` in index order, so a dropped neighbour or an unfiltered pair shows.
    """

    def radius(x, y, r, batch_x, batch_y, max_num_neighbors):
        calls.append(max_num_neighbors)
        close = (torch.cdist(y.double(), x.double()) <= r) & (batch_y[:, None] == batch_x[None])
        kept = close & (torch.cumsum(close.long(), dim=1) <= max_num_neighbors)
        query, neighbour = kept.nonzero(as_tuple=True)
        return torch.stack([query, neighbour])

    return types.SimpleNamespace(radius=radius)


@pytest.fixture
def search_calls(monkeypatch):
    calls: list[int] = []
    monkeypatch.setitem(sys.modules, "torch_cluster", stand_in_torch_cluster(calls))
    return calls


def test_the_cap_doubles_until_no_particle_reaches_it(search_calls):
    # Nine particles within R of each other: each has 9 neighbours, so caps 2, 4 and 8 are reached and 16 is not.
    position = torch.rand(9, 2, generator=torch.Generator().manual_seed(0)) * 0.01
    batch = torch.zeros(9, dtype=torch.long)
    graph = build("radius_torch_cluster", small_scene(2, 0.1), position, batch, 1, initial_max_neighbors=2)
    assert search_calls == [2, 4, 8, 16]
    assert edge_set(graph) == {(s, r) for s in range(9) for r in range(9)}


def test_the_widened_search_is_filtered_to_the_strict_radius(search_calls):
    # R = 0.5: particle 1 is exactly R from 0 and particle 2 is 0.5002 from 0, inside the search margin of 2^-10 R.
    position = torch.tensor([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5002], [0.3, 0.0]])
    graph = build("radius_torch_cluster", small_scene(2, 0.5), position, torch.zeros(4).long(), 1)
    assert edge_set(graph) == edge_set(build("radius", small_scene(2, 0.5), position, torch.zeros(4).long(), 1))
    assert (1, 0) not in edge_set(graph) and (2, 0) not in edge_set(graph) and (3, 0) in edge_set(graph)


def test_edges_are_sorted_by_receiver_then_sender_as_the_radius_builder_gives_them(search_calls):
    position, batch = random_positions(3, [30, 20], seed=1, spread=0.6)
    ours = build("radius_torch_cluster", small_scene(3, 0.2), position, batch, 2, initial_max_neighbors=3)
    reference = build("radius", small_scene(3, 0.2), position, batch, 2)
    assert torch.equal(ours.senders, reference.senders) and torch.equal(ours.receivers, reference.receivers)
    torch.testing.assert_close(ours.displacement, position[ours.senders] - position[ours.receivers], rtol=0, atol=0)


def test_no_particles_give_no_edges(search_calls):
    graph = build("radius_torch_cluster", small_scene(2), torch.zeros(0, 2), torch.zeros(0, dtype=torch.long), 1)
    assert graph.senders.numel() == 0 and search_calls == [64], "one search at the default cap"


def test_torch_cluster_builder_without_torch_cluster_says_what_to_install(monkeypatch):
    # A None entry makes the import fail as it does where torch-cluster is not installed.
    monkeypatch.setitem(sys.modules, "torch_cluster", None)
    cls = REGISTRY.get("graph_builder", "radius_torch_cluster")
    with pytest.raises(PluginError, match="pip install torch-cluster"):
        cls(cls.Params(), small_scene())


def test_with_torch_cluster_installed_it_gives_the_radius_edges():
    pytest.importorskip("torch_cluster")
    position, batch = random_positions(2, [40, 25], seed=7, spread=0.5)
    ours = build("radius_torch_cluster", small_scene(2, 0.1), position.float(), batch, 2, initial_max_neighbors=2)
    reference = build("radius", small_scene(2, 0.1), position.float(), batch, 2)
    assert torch.equal(ours.senders, reference.senders) and torch.equal(ours.receivers, reference.receivers)
