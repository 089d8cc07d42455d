"""Start test processes with torch.multiprocessing and fail the test, not hang it, when they do not finish."""

from __future__ import annotations

import socket
import time

import pytest
import torch


def run_processes(function, args: tuple, processes: int = 2, seconds: float = 240) -> None:
    """``function(rank, *args)`` in ``processes`` spawned processes; fails the test after ``seconds``."""
    context = torch.multiprocessing.spawn(function, args=args, nprocs=processes, join=False)
    deadline = time.monotonic() + seconds
    while not context.join(timeout=2):
        if time.monotonic() > deadline:
            for process in context.processes:
                process.kill()
            pytest.fail(f"{processes} processes did not finish within {seconds} s")


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 now (for a process group's rendezvous)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
