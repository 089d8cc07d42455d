"""SyncCounter: the operators that would make the host wait for a GPU, counted on the CPU."""

from __future__ import annotations

import torch

from gns_framework.runtime.sync_counter import SyncCounter


def test_the_sync_counter_sees_waits_inside_torch():
    x = torch.arange(6)
    with SyncCounter() as counter:
        x[x > 2]
        torch.unique(x)
        x.sum().item()
        torch.repeat_interleave(x, x)
        torch.repeat_interleave(x, x, output_size=15)
        x[torch.tensor([0, 1])]
    assert counter.counts == {
        "aten.index (boolean mask)": 1,
        "aten._unique2": 1,
        "aten._local_scalar_dense": 1,
        "aten.repeat_interleave (no output_size)": 1,
    }
