"""The empty graph: no edges at all, and a grid model built on it still couples neighbouring particles."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from graph_cases import build

from gns_framework.testing import small_scene, small_sizes


@pytest.mark.parametrize("dim", [2, 3])
def test_no_particle_has_a_neighbour(dim):
    position = torch.rand(17, dim, dtype=torch.float64)
    batch = torch.tensor([0] * 9 + [1] * 8)
    graph = build("no_edges", small_scene(dim), position, batch, 2)
    assert graph.num_nodes == 17 and graph.num_edges == 0
    assert graph.senders.dtype == graph.receivers.dtype == torch.long
    assert graph.displacement.shape == (0, dim) and graph.displacement.dtype == position.dtype


def test_the_grid_processor_couples_particles_without_edges():
    """What one particle's latent becomes depends on a particle one cell away, through the grid alone."""
    from gns_builtins.processors.grid_cnn import GridProcessor

    torch.manual_seed(0)
    sizes = small_sizes()
    processor = GridProcessor(GridProcessor.Params(message_passing_steps=1, conv_layers=2), sizes).double()
    position = torch.tensor([[0.20, 0.20], [0.28, 0.21], [0.90, 0.90]], dtype=torch.float64)
    graph = build("no_edges", small_scene(), position, torch.zeros(3, dtype=torch.long), 1)
    graph = dataclasses.replace(graph, position=position)
    latent = torch.randn(3, sizes.latent, dtype=torch.float64, requires_grad=True)
    edges = torch.zeros(0, sizes.latent, dtype=torch.float64)
    out, _ = processor(latent, edges, graph)
    # A random readout: the sum of a layer-normed latent has zero gradient in exact arithmetic, so a plain sum
    # would leave the coupling to round-off.
    readout = torch.randn(sizes.latent, dtype=torch.float64)
    (grad,) = torch.autograd.grad(out[0] @ readout, latent)
    assert grad[1].abs().sum() > 1e-6 * grad[0].abs().sum(), "the neighbour one cell away reaches particle 0"
    assert grad[2].abs().sum() == 0, "a particle beyond the convolutions' reach does not"
