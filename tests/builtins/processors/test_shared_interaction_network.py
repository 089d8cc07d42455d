"""The shared interaction network: one interaction step applied M times with the same weights."""

from __future__ import annotations

import pytest
import torch

from gns_builtins.processors.interaction_network import InteractionNetwork, InteractionStep
from gns_builtins.processors.shared_interaction_network import SharedInteractionNetwork
from gns_framework.contracts import Graph
from gns_framework.testing import small_sizes


def case(seed=0, n=12, dtype=torch.float64):
    """A random graph with self-edges and latents of width 16."""
    generator = torch.Generator().manual_seed(seed)
    adjacency = (torch.rand(n, n, generator=generator) < 0.3) | torch.eye(n, dtype=torch.bool)
    receivers, senders = adjacency.nonzero(as_tuple=True)
    position = torch.rand(n, 2, generator=generator, dtype=dtype)
    graph = Graph(senders, receivers, position[senders] - position[receivers], n)
    x = torch.randn(n, 16, generator=generator, dtype=dtype)
    e = torch.randn(senders.numel(), 16, generator=generator, dtype=dtype)
    return graph, x, e


def shared(steps=3, edge_block="plain", seed=0):
    torch.manual_seed(seed)
    params = SharedInteractionNetwork.Params(message_passing_steps=steps, edge_block=edge_block)
    return SharedInteractionNetwork(params, small_sizes()).double()


def test_it_has_the_parameters_of_one_step_whatever_m():
    one_step = InteractionStep(16, 16, 2)
    count = sum(p.numel() for p in one_step.parameters())
    for steps in (1, 4, 10):
        assert sum(p.numel() for p in shared(steps).parameters()) == count


def test_m_steps_are_the_one_step_applied_m_times():
    processor = shared(steps=3)
    graph, x, e = case()
    expected_x, expected_e = x, e
    for _ in range(3):
        expected_x, expected_e = processor.step(expected_x, expected_e, graph.senders, graph.receivers)
    out_x, out_e = processor(x, e, graph)
    torch.testing.assert_close(out_x, expected_x, rtol=0, atol=0)
    torch.testing.assert_close(out_e, expected_e, rtol=0, atol=0)


def test_it_equals_the_unshared_network_with_every_step_given_the_same_weights():
    processor = shared(steps=3)
    unshared = InteractionNetwork(
        InteractionNetwork.Params(message_passing_steps=3, edge_block="plain"), small_sizes()
    ).double()
    for step in unshared.steps:
        step.load_state_dict(processor.step.state_dict())
    graph, x, e = case(seed=1)
    for got, expected in zip(processor(x, e, graph), unshared(x, e, graph), strict=True):
        torch.testing.assert_close(got, expected, rtol=0, atol=0)


def test_more_steps_reach_further():
    # Three hops in a chain 0 -> 1 -> 2 -> 3: with M = 2 node 3 cannot feel node 0, with M = 3 it does.
    senders, receivers = torch.tensor([0, 1, 2, 0, 1, 2, 3]), torch.tensor([1, 2, 3, 0, 1, 2, 3])
    graph = Graph(senders, receivers, torch.zeros(7, 2, dtype=torch.float64), 4)
    generator = torch.Generator().manual_seed(2)
    x, e = torch.randn(4, 16, generator=generator, dtype=torch.float64), torch.randn(7, 16, dtype=torch.float64)
    moved = x.clone()
    moved[0] += 1.0
    for steps, reaches in ((2, False), (3, True)):
        processor = shared(steps)
        changed = not torch.equal(processor(x, e, graph)[0][3], processor(moved, e, graph)[0][3])
        assert changed is reaches, steps


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fused_edge_block_equals_the_plain_one_in_float64(seed):
    fused, plain = shared(edge_block="fused", seed=seed), shared(edge_block="plain", seed=seed)
    plain.load_state_dict(fused.state_dict())
    graph, x, e = case(seed=seed)
    for got, expected in zip(fused(x, e, graph), plain(x, e, graph), strict=True):
        # One function evaluated twice in float64: rounding of O(1) latents after three steps only.
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-11)
