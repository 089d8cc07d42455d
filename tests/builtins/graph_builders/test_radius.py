"""The radius graph builder: the cell list's pairs at the scene's connectivity radius, with their displacements.

The search itself (brute force, strict radius, invariances, chunks) is tested in
tests/builtins/_kernels/test_cell_list.py.
"""

from __future__ import annotations

import torch

from gns_builtins.graph_builders.radius import RadiusGraphBuilder
from gns_framework.contracts import ModelSetup


def test_builder_returns_displacements():
    scene = ModelSetup(dim=2, bounds=((0, 1), (0, 1)), connectivity_radius=0.3, particle_types=(5,))
    position = torch.tensor([[0.1, 0.1], [0.3, 0.1]])
    graph = RadiusGraphBuilder(RadiusGraphBuilder.Params(), scene).build(position, torch.zeros(2, dtype=torch.long), 1)
    for s, r, d in zip(graph.senders, graph.receivers, graph.displacement, strict=True):
        assert torch.equal(d, position[s] - position[r])


def test_builder_connects_within_the_connectivity_radius_and_within_each_example():
    # R = 0.25: 0 and 1 are 0.2 apart, 2 is 0.3 from 1; 3 sits on 0 but belongs to another example.
    scene = ModelSetup(dim=2, bounds=((0, 1), (0, 1)), connectivity_radius=0.25, particle_types=(5,))
    position = torch.tensor([[0.0, 0.0], [0.2, 0.0], [0.5, 0.0], [0.0, 0.0]])
    graph = RadiusGraphBuilder(RadiusGraphBuilder.Params(), scene).build(position, torch.tensor([0, 0, 0, 1]), 2)
    # Sorted by receiver, then sender; self-edges included.
    assert graph.senders.tolist() == [0, 1, 0, 1, 2, 3]
    assert graph.receivers.tolist() == [0, 0, 1, 1, 2, 3]
    assert graph.num_nodes == 4


def test_a_skin_gives_the_same_graph_every_frame_and_searches_less():
    scene = ModelSetup(dim=2, bounds=((0, 1), (0, 1)), connectivity_radius=0.04, particle_types=(5,))
    plain = RadiusGraphBuilder(RadiusGraphBuilder.Params(), scene)
    skinned = RadiusGraphBuilder(RadiusGraphBuilder.Params(skin=0.5), scene)
    assert plain.verlet is None and skinned.verlet is not None
    generator = torch.Generator().manual_seed(3)
    position = torch.rand(300, 2, generator=generator)
    batch = torch.zeros(300, dtype=torch.long)
    for _ in range(30):
        # A settling pile: most particles still, a few moving 1 mm a frame.
        position = position.clone()
        position[:30] += 1e-3 * torch.randn(30, 2, generator=generator)
        expected, graph = plain.build(position, batch, 1), skinned.build(position, batch, 1)
        assert torch.equal(graph.senders, expected.senders) and torch.equal(graph.receivers, expected.receivers)
        assert torch.equal(graph.displacement, expected.displacement)
    assert skinned.verlet.searches < 10
