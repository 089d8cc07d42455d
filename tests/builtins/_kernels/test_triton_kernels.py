"""The segmented-sum kernel on its own: each node's run summed in order, through the senders' transpose too.

(The edge kernels are tested through their wrapper, test_triton_edge_block.py.)
"""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels import triton_edge_block
from gns_builtins._kernels.edge_order import EdgeOrder

pytest.importorskip("triton")


DEVICE = torch.device("cuda" if torch.cuda.is_available() else "cpu")


@pytest.fixture(autouse=True)
def interpreted():
    if DEVICE.type == "cpu" and not triton_edge_block.interpreted():
        pytest.skip("Triton's interpreter is off (TRITON_INTERPRET=1 is set by tests/conftest.py without a GPU)")


def test_segment_sums_by_receiver_and_by_sender_into_halves_of_a_table():
    generator = torch.Generator().manual_seed(0)
    receivers = torch.cat([torch.randint(0, 11, (60,), generator=generator), torch.full((140,), 4)]).sort().values
    senders = torch.randint(0, 11, (receivers.numel(),), generator=generator)
    rows = torch.randn(receivers.numel(), 16, generator=generator)
    order = EdgeOrder.of(senders.to(DEVICE), receivers.to(DEVICE), 11)
    table = torch.ones(22, 16, device=DEVICE)
    triton_edge_block.segment_sum_into(table, 0, rows.to(DEVICE), order.receiver_offsets, None)
    triton_edge_block.segment_sum_into(table, 11, rows.to(DEVICE), order.sender_offsets, order.sender_permutation)
    table = table.cpu()
    by_receiver = torch.ones(11, 16, dtype=torch.float64).index_add(0, receivers, rows.double())
    by_sender = torch.ones(11, 16, dtype=torch.float64).index_add(0, senders, rows.double())
    scale = rows.abs().sum() * torch.finfo(torch.float32).eps
    assert (table[:11].double() - by_receiver).abs().max() <= scale
    assert (table[11:].double() - by_sender).abs().max() <= scale
    wrong = torch.ones(11, 16, dtype=torch.float64).index_add(0, senders.roll(1), rows.double())
    assert (table[11:].double() - wrong).abs().max() > scale, "the tolerance catches a wrong sender"
