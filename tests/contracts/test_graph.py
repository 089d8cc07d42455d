"""The graph record: its edge count, the defaults a builder may leave out, and that it cannot be changed."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from gns_framework.contracts import Graph


def _graph(edges: int, **fields) -> Graph:
    receivers = torch.zeros(edges, dtype=torch.long)
    return Graph(torch.arange(edges), receivers, torch.zeros(edges, 2), num_nodes=max(edges, 1), **fields)


@pytest.mark.parametrize("edges", [0, 1, 5])
def test_num_edges_counts_the_senders(edges):
    assert _graph(edges).num_edges == edges
    assert isinstance(_graph(edges).num_edges, int)


def test_a_builder_may_leave_out_positions_and_batch_of_one_example():
    graph = _graph(3)
    assert graph.position is None and graph.batch is None and graph.num_examples == 1
    assert graph.exchange is None  # set only in a domain-decomposed step


def test_the_learned_simulator_may_attach_positions_and_the_batch():
    position, batch = torch.zeros(4, 2), torch.tensor([0, 0, 1, 1])
    graph = _graph(4, position=position, batch=batch, num_examples=2)
    assert graph.position is position and graph.batch is batch and graph.num_examples == 2


def test_a_graph_is_frozen():
    # Processors share one graph across message-passing steps: none may change it under the others.
    with pytest.raises(dataclasses.FrozenInstanceError):
        _graph(2).num_nodes = 7


def test_received_by_keeps_the_edges_into_owned_particles_in_order_with_the_exchange():
    graph = Graph(
        senders=torch.tensor([1, 2, 0, 2, 0, 1]),
        receivers=torch.tensor([0, 0, 1, 1, 2, 2]),
        displacement=torch.arange(12.0).reshape(6, 2),
        num_nodes=3,
        receivers_sorted=True,
    )
    exchange = torch.neg
    piece = graph.received_by(torch.tensor([True, False, True]), exchange)
    assert piece.senders.tolist() == [1, 2, 0, 1] and piece.receivers.tolist() == [0, 0, 2, 2]
    assert piece.displacement[:, 0].tolist() == [0.0, 2.0, 8.0, 10.0]
    assert piece.exchange is exchange and piece.receivers_sorted and piece.num_nodes == 3
