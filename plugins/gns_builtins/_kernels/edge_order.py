"""The two orders of a graph's edges that sums at nodes need, made once per graph, never per call.

Messages are summed at receivers (forward) and their gradients at receivers and at
senders (backward). Built-in builders sort edges by receiver, so the edges of
receiver ``i`` are the contiguous run ``[receiver_offsets[i], receiver_offsets[i + 1])``
(compressed sparse rows, CSR); the senders' runs need a permutation, the graph's
transpose. Summing each run in its own order gives the same bits run after run
without atomics, and with the offsets made once per graph (not per backward
call) a message-passing step spends nothing on sorting.

All of it is computed on the device with no read-back: the offsets come from a
binary search of the sorted keys (``searchsorted``), the transpose from one stable sort.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py


def run_offsets(sorted_keys: Tensor, num_keys: int) -> Tensor:
    """(num_keys + 1,) int64: ``offsets[i]`` is the first position whose key is >= i.

    Shapes: sorted_keys (E,) non-decreasing, in [0, num_keys).
    """
    bounds = torch.arange(num_keys + 1, device=sorted_keys.device, dtype=sorted_keys.dtype)
    return torch.searchsorted(sorted_keys, bounds)


class EdgeOrder(NamedTuple):
    """Where each node's edges are, as receiver and as sender.

    Attributes:
        receiver_offsets: (N + 1,) int64 CSR offsets of the receiver-sorted edges.
        sender_permutation: (E,) int64 edge indices sorted by sender (stable: by receiver within a sender).
        sender_offsets: (N + 1,) int64 CSR offsets into ``sender_permutation``.
    """

    receiver_offsets: Tensor
    sender_permutation: Tensor
    sender_offsets: Tensor

    @staticmethod
    def of(senders: Tensor, receivers: Tensor, num_nodes: int) -> EdgeOrder:
        """The orders of a graph whose edges are sorted by receiver (as every built-in builder returns them).

        Shapes: senders, receivers (E,) int64; ``receivers`` non-decreasing (not checked: that would be a
        read-back; :func:`check` does it in tests).
        """
        permutation = torch.argsort(senders, stable=True)
        return EdgeOrder(run_offsets(receivers, num_nodes), permutation, run_offsets(senders[permutation], num_nodes))


def check(order: EdgeOrder, senders: Tensor, receivers: Tensor) -> None:
    """Raise ValueError unless ``order`` describes these edges (a test helper: it reads values back)."""
    if receivers.numel() and not bool((receivers[1:] >= receivers[:-1]).all()):
        raise ValueError("the edges are not sorted by receiver")
    counts = torch.bincount(receivers, minlength=order.receiver_offsets.numel() - 1)
    if not torch.equal(order.receiver_offsets.diff(), counts):
        raise ValueError("receiver_offsets do not count the edges of each receiver")
    if not bool((senders[order.sender_permutation].diff() >= 0).all()):
        raise ValueError("sender_permutation does not sort the senders")
