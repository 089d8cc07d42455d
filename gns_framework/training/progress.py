"""How fast a training run goes: throughput between logs, and the time it has left."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

from ..runtime.device import synchronize
from ..runtime.processes import Processes


class Throughput:
    """Optimiser steps and particles per second since the last log, over the optimiser steps alone.

    Validation and checkpoints stop the clock (:meth:`pause`); it restarts at the next
    step, timed from one device synchronisation to the next so that queued GPU work
    is counted.
    """

    def __init__(self, device: torch.device):
        self.device = device
        self.steps, self.particles = 0, 0
        self.started: float | None = None

    def step_starts(self) -> None:
        if self.started is None:
            synchronize(self.device)
            self.started = time.perf_counter()

    def step_done(self, particles: int) -> None:
        self.steps, self.particles = self.steps + 1, self.particles + particles

    def pause(self) -> None:
        self.started = None

    def read(self) -> dict[str, float]:
        """``steps_per_s`` and ``particles_per_s`` since the last read (or pause), and a fresh window."""
        assert self.started is not None, "read after a step"
        synchronize(self.device)
        seconds = time.perf_counter() - self.started
        figures = {"steps_per_s": self.steps / seconds, "particles_per_s": self.particles / seconds}
        self.steps, self.particles, self.started = 0, 0, None
        return figures


def time_to_go(step: int, total: int, done: int, seconds: float) -> str:
    """``step 100 of 40000, 2.31 steps/s: about 4 h 48 min to go``, at the pace since this run (re)started.

    The pace counts everything the loop does (validations and checkpoints too), so it
    is what the clock will show.
    """
    if done < 1 or seconds <= 0:
        return f"step {step} of {total}"
    pace = done / seconds
    left = (total - step) / pace
    minutes = round(left / 60)
    span = f"{minutes // 60} h {minutes % 60} min" if minutes >= 60 else f"{max(minutes, 1)} min"
    return f"step {step} of {total}, {pace:.3g} steps/s: about {span} to go"


class Deadline:
    """Whether a run has used its time (``gns train --time-limit``): every process stops after the same step.

    One process looks at its clock after every step. Several agree at the steps that log,
    where rank 0's clock decides for all (a broadcast there only): clocks differ, and a
    process that stopped alone would leave the others waiting in their collectives.
    """

    clock: Callable[[], float] = staticmethod(time.monotonic)
    """Seconds from any origin (a class attribute, so that a test can set the time)."""

    def __init__(self, seconds: float | None, processes: Processes):
        self.seconds, self.processes = seconds, processes
        self.started = self.clock()
        self.reached = False

    def passed(self, logs: bool) -> bool:
        """Whether the time is used, after a step (``logs``: one that logs)."""
        if self.seconds is None:
            return False
        if not self.processes.distributed:
            self.reached = self.clock() - self.started >= self.seconds
        elif logs:
            self.reached = bool(self.processes.broadcast(self.clock() - self.started >= self.seconds))
        return self.reached
