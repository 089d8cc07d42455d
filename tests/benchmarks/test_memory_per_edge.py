"""benchmarks/memory_per_edge.py: the profiler-based peak sees what a step holds at once."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from memory_per_edge import step_peak_bytes


def test_the_peak_is_what_is_held_at_once_not_what_is_allocated_in_all():
    kept = []

    def step():
        for _ in range(3):
            transient = torch.ones(1 << 18)  # 1 MiB, freed at the next iteration
        kept.append(torch.ones(1 << 19))  # 2 MiB, held after the step
        del transient

    peak = step_peak_bytes(step)
    assert 3 * 2**20 <= peak < 4 * 2**20, peak
