"""The graph-attention processor: messages flow sender to receiver, weighted to sum to one, and the edge updates."""

from __future__ import annotations

import copy

import pytest
import torch

from gns_builtins.processors.graph_attention import GraphAttentionProcessor
from gns_framework.contracts import Graph
from gns_framework.testing import small_sizes


def processor(steps=2, heads=2, seed=0):
    torch.manual_seed(seed)
    params = GraphAttentionProcessor.Params(message_passing_steps=steps, heads=heads)
    return GraphAttentionProcessor(params, small_sizes()).double()


def graph_of(senders, receivers, n):
    senders, receivers = torch.tensor(senders), torch.tensor(receivers)
    return Graph(senders, receivers, torch.zeros(senders.numel(), 2, dtype=torch.float64), n)


def latents(n, edges, seed=0):
    generator = torch.Generator().manual_seed(seed)
    x = torch.randn(n, 16, generator=generator, dtype=torch.float64)
    return x, torch.randn(edges, 16, generator=generator, dtype=torch.float64)


def test_heads_must_divide_the_latent_size():
    with pytest.raises(ValueError, match=r"graph_attention: heads \(3\) must divide latent_size \(16\)"):
        GraphAttentionProcessor(GraphAttentionProcessor.Params(heads=3), small_sizes())


def test_messages_flow_from_sender_to_receiver():
    # Self-edges everywhere and one edge 0 -> 1: only node 1 listens to node 0, and node 0 to no one else.
    graph = graph_of([0, 1, 2, 0], [0, 1, 2, 1], 3)
    step_one = processor(steps=1)
    x, e = latents(3, 4)
    base, _ = step_one(x, e, graph)
    for changed, listeners in ((0, {0, 1}), (1, {1})):
        moved = x.clone()
        moved[changed] += 1.0
        out, _ = step_one(moved, e, graph)
        differs = {i for i in range(3) if not torch.equal(out[i], base[i])}
        assert differs == listeners, changed


def test_attention_weighs_the_incoming_messages_to_sum_to_one():
    # Every node and edge alike: node 1 receives three identical messages and node 0 one. A sum would give node 1
    # three times node 0's aggregate; softmax weights (1/3 each) give it the same, so the two nodes end alike.
    graph = graph_of([0, 1, 2, 3, 2, 3], [0, 1, 2, 3, 1, 1], 4)
    step_one = processor(steps=1)
    x = torch.randn(1, 16, dtype=torch.float64).expand(4, 16).clone()
    e = torch.randn(1, 16, dtype=torch.float64).expand(6, 16).clone()
    out, _ = step_one(x, e, graph)
    # The same float64 operations on the same values, up to the order of a softmax over 1 or 3 terms.
    torch.testing.assert_close(out[1], out[0], rtol=0, atol=1e-12)


def test_a_step_is_attention_then_the_node_and_edge_updates_with_residuals():
    graph = graph_of([0, 1, 2, 0, 2, 1], [0, 1, 2, 1, 1, 2], 3)
    layer = processor(steps=2)
    x, e = latents(3, 6)
    step = layer.steps[0]
    s, r = graph.senders, graph.receivers
    aggregate = step.attention(x, torch.stack([s, r]), e)
    x_new = x + step.node_mlp(torch.cat([x, aggregate], dim=-1))
    # The edge sees its receiver's and sender's updated latents, in that order.
    e_new = e + step.edge_mlp(torch.cat([e, x_new[r], x_new[s]], dim=-1))
    out_x, out_e = step(x, e, s, r)
    torch.testing.assert_close(out_x, x_new, rtol=0, atol=0)
    torch.testing.assert_close(out_e, e_new, rtol=0, atol=0)


def test_the_last_step_leaves_the_edges_as_they_are():
    # Nothing reads the last edge latent, so the last step has no edge MLP (DDP refuses unused parameters).
    layer = processor(steps=3)
    assert [step.edge_mlp is None for step in layer.steps] == [False, False, True]
    graph = graph_of([0, 1, 0], [0, 1, 1], 2)
    x, e = latents(2, 3)
    _, out_e = processor(steps=1)(x, e, graph)
    assert torch.equal(out_e, e)


def test_the_steps_are_applied_in_order_with_their_own_weights():
    layer = processor(steps=2)
    graph = graph_of([0, 1, 2, 0, 2], [0, 1, 2, 1, 0], 3)
    x, e = latents(3, 5)
    x1, e1 = layer.steps[0](x, e, graph.senders, graph.receivers)
    expected = layer.steps[1](x1, e1, graph.senders, graph.receivers)
    for got, want in zip(layer(x, e, graph), expected, strict=True):
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    swapped = copy.deepcopy(layer)
    swapped.steps[0].load_state_dict(layer.steps[1].state_dict(), strict=False)
    assert not torch.allclose(swapped(x, e, graph)[0], layer(x, e, graph)[0]), "the steps' weights differ"


def test_it_is_equivariant_to_the_order_of_particles_and_edges():
    layer = processor(steps=2)
    generator = torch.Generator().manual_seed(4)
    n = 10
    adjacency = (torch.rand(n, n, generator=generator) < 0.35) | torch.eye(n, dtype=torch.bool)
    receivers, senders = adjacency.nonzero(as_tuple=True)
    x, e = latents(n, senders.numel(), seed=5)
    out_x, out_e = layer(x, e, Graph(senders, receivers, torch.zeros(senders.numel(), 2, dtype=torch.float64), n))
    perm = torch.randperm(n, generator=generator)
    inverse = torch.argsort(perm)
    edge_perm = torch.randperm(senders.numel(), generator=generator)
    permuted = Graph(inverse[senders][edge_perm], inverse[receivers][edge_perm], torch.zeros(senders.numel(), 2), n)
    px, pe = layer(x[perm], e[edge_perm], permuted)
    # Sums over a receiver's edges in another order: float64 rounding of O(1) latents.
    torch.testing.assert_close(px, out_x[perm], rtol=0, atol=1e-10)
    torch.testing.assert_close(pe, out_e[edge_perm], rtol=0, atol=1e-10)
