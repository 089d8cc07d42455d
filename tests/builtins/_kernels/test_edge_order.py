"""A graph's edge orders: receiver runs, the senders' transpose and its runs, made on the device without read-backs."""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels.edge_order import EdgeOrder, check, run_offsets


def sorted_edges(num_nodes=9, num_edges=40, seed=0):
    generator = torch.Generator().manual_seed(seed)
    receivers = torch.randint(0, num_nodes, (num_edges,), generator=generator)
    senders = torch.randint(0, num_nodes, (num_edges,), generator=generator)
    order = torch.argsort(receivers * num_nodes + senders)
    return senders[order], receivers[order]


def test_runs_cover_each_nodes_edges():
    senders, receivers = sorted_edges()
    order = EdgeOrder.of(senders, receivers, 9)
    check(order, senders, receivers)
    for node in range(9):
        lo, hi = order.receiver_offsets[node : node + 2].tolist()
        assert torch.equal(torch.nonzero(receivers == node)[:, 0], torch.arange(lo, hi))
        lo, hi = order.sender_offsets[node : node + 2].tolist()
        run = order.sender_permutation[lo:hi]
        assert torch.equal(run, torch.nonzero(senders == node)[:, 0]), "stable: each sender's edges in edge order"


def test_nodes_without_edges_and_no_edges_at_all():
    assert run_offsets(torch.tensor([2, 2, 5]), 7).tolist() == [0, 0, 0, 2, 2, 2, 3, 3]
    empty = torch.zeros(0, dtype=torch.long)
    order = EdgeOrder.of(empty, empty, 4)
    assert order.receiver_offsets.tolist() == [0] * 5 and order.sender_offsets.tolist() == [0] * 5


def test_check_refuses_unsorted_receivers():
    senders, receivers = sorted_edges()
    order = EdgeOrder.of(senders, receivers, 9)
    with pytest.raises(ValueError, match="not sorted by receiver"):
        check(order, senders, receivers.flip(0))
