"""Honest wall-clock timing: warm-up excluded, median of repeats, device synchronised.

A speed-up is only as good as the timings behind it, so every measurement
carries the hardware it ran on (:func:`hardware_description`).
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import torch

from ..runtime.device import is_cuda, synchronize

T = TypeVar("T")


@dataclass(frozen=True)
class Timing:
    """Wall-clock seconds of the timed repeats (warm-up runs not included)."""

    seconds: tuple[float, ...]
    warmup: int

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)

    @property
    def spread(self) -> float:
        """max - min of the repeats, s: how far to trust the median."""
        return max(self.seconds) - min(self.seconds)


def time_call(
    fn: Callable[[], T],
    *,
    repeats: int = 5,
    warmup: int = 1,
    device: torch.device | str | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[T, Timing]:
    """Run ``fn`` ``warmup`` times untimed, then ``repeats`` times timed by ``clock`` (seconds).

    The device is synchronised before starting and before stopping each clock,
    so asynchronous GPU work is counted where it happens. Returns the result of
    the last timed call and the timing.
    """
    if repeats < 1 or warmup < 0:
        raise ValueError(f"need repeats >= 1 and warmup >= 0, got repeats={repeats}, warmup={warmup}")
    for _ in range(warmup):
        fn()
    seconds = []
    result: T  # set by the first of the repeats (at least one)
    for _ in range(repeats):
        synchronize(device)
        start = clock()
        result = fn()
        synchronize(device)
        seconds.append(clock() - start)
    return result, Timing(tuple(seconds), warmup)


def _cpu_model() -> str:
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def hardware_description(device: torch.device | str | None = None) -> dict[str, str | int]:
    """What a timing ran on: CPU model, cores usable and in total, torch threads, GPU."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    description: dict[str, str | int] = {
        "cpu": _cpu_model(),
        "cpu_cores_total": os.cpu_count() or 0,
        "cpu_cores_usable": usable or 0,
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "device": str(device or "cpu"),
    }
    if is_cuda(device):
        description["gpu"] = torch.cuda.get_device_name(device)
    return description


def format_hardware(description: dict[str, str | int]) -> str:
    """One line for report headers and logs."""
    line = (
        f"{description['cpu']}, {description['cpu_cores_usable']} of {description['cpu_cores_total']} cores usable, "
        f"{description['torch_threads']} torch threads, torch {description['torch']}, device {description['device']}"
    )
    if "gpu" in description:
        line += f" ({description['gpu']})"
    return line
