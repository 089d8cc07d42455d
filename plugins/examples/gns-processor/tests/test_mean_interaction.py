"""The example processor conforms, averages its messages, and is found through its entry point."""

import torch
from gns_example_processor import MeanInteractionNetwork

from gns_framework.contracts import Graph
from gns_framework.plugins import load_registry
from gns_framework.testing import check_processor, small_sizes


def test_conforms():
    check_processor(MeanInteractionNetwork, {"message_passing_steps": 2})


def test_each_edge_twice_gives_the_same_nodes():
    """A mean does not see how many times a message arrives (a sum would double)."""
    sizes = small_sizes()
    processor = MeanInteractionNetwork(MeanInteractionNetwork.Params(message_passing_steps=2), sizes).double()
    generator = torch.Generator().manual_seed(0)
    senders, receivers = torch.tensor([0, 1, 1, 2, 0]), torch.tensor([0, 0, 1, 1, 2])
    graph = Graph(senders, receivers, torch.randn(5, sizes.dim, generator=generator, dtype=torch.float64), 3)
    twice = Graph(senders.repeat(2), receivers.repeat(2), graph.displacement.repeat(2, 1), 3)
    x = torch.randn(3, sizes.latent, generator=generator, dtype=torch.float64)
    e = torch.randn(5, sizes.latent, generator=generator, dtype=torch.float64)
    x_once, e_once = processor(x, e, graph)
    x_twice, e_twice = processor(x, e.repeat(2, 1), twice)
    assert torch.allclose(x_twice, x_once) and torch.allclose(e_twice, e_once.repeat(2, 1))


def test_is_registered_by_its_entry_point():
    entry = load_registry().entry("processor", "mean_interaction_network")
    assert entry.cls is MeanInteractionNetwork
    assert entry.distribution == "gns-example-processor" and entry.plugin == "example-processor"
