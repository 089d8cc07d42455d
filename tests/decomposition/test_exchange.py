"""Rows sent to the processes that need them, in one all-to-all per tensor (decomposition/exchange.py)."""

from __future__ import annotations

import torch
from decomposition_cases import exchange_worker
from spawned import free_loopback_port, run_processes

from gns_framework.decomposition.exchange import send_rows


def test_one_process_keeps_every_row_in_order():
    rows = [torch.arange(4), torch.ones(4, 2), None]
    kept = send_rows(torch.zeros(4, dtype=torch.long), rows, world_size=1)
    assert kept[0] is rows[0] and kept[1] is rows[1] and kept[2] is None


def test_three_processes_receive_their_rows_ordered_by_sender(tmp_path):
    world = 3
    run_processes(exchange_worker, (world, free_loopback_port(), str(tmp_path)), world, seconds=120)
    for rank in range(world):
        got = torch.load(tmp_path / f"rank{rank}.pt", weights_only=True)
        # Sender s sends its row i to rank (s + i) % world: rank r gets rows i = (r - s) % world + k * world.
        expected = [
            100 * sender + i for sender in range(world) for i in range(2 * world) if (sender + i) % world == rank
        ]
        assert got["label"].tolist() == expected
        assert torch.equal(got["pairs"], torch.stack([got["label"], -got["label"]], dim=1).double())
        assert got["flags"].dtype == torch.bool and got["flags"].tolist() == [x % 2 == 0 for x in expected]
        assert got["none"] is None


def test_one_process_holds_its_own_object_only():
    from gns_framework.decomposition.exchange import objects_everywhere
    from gns_framework.runtime.processes import Processes

    report = {"clamped": [3, 5]}
    assert objects_everywhere(Processes(), report) == [report]
