"""The processor contract: a learned part that must define forward(node_latent, edge_latent, graph)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Graph, LearnedPart, ModelSizes, Params, Processor

SIZES = ModelSizes(node_in=5, edge_in=3, latent=4, mlp_hidden=4, mlp_hidden_layers=1, output=2, dim=2)


def test_a_processor_without_forward_cannot_be_built():
    class NoForward(Processor):
        name = "no_forward"

    with pytest.raises(TypeError, match="abstract method forward"):
        NoForward(Params(), SIZES)


def test_a_processor_with_forward_passes_messages_over_the_graph_it_is_given():
    class SumAtReceivers(Processor):
        """One step of message passing without weights: each node adds the edge latents arriving at it."""

        name = "sum_at_receivers"

        def forward(self, node_latent, edge_latent, graph):
            return node_latent.index_add(0, graph.receivers, edge_latent), edge_latent

    processor = SumAtReceivers(Params(), SIZES)
    assert isinstance(processor, LearnedPart)
    # Edges 0 -> 1 and 2 -> 1: node 1 receives both, the others none.
    graph = Graph(torch.tensor([0, 2]), torch.tensor([1, 1]), torch.zeros(2, 2), num_nodes=3)
    nodes, edges = processor(torch.zeros(3, SIZES.latent), torch.ones(2, SIZES.latent), graph)
    assert nodes[:, 0].tolist() == [0.0, 2.0, 0.0] and edges.shape == (2, SIZES.latent)


def test_by_default_a_processor_bounds_no_hops_and_exchanges_no_latents():
    """What a domain decomposition reads (decomposition/halo.py): unknown reach, no exchange between steps."""
    assert Processor.hops_param is None and Processor.exchanges_latents is False
