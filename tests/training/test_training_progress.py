"""A training run's pace: throughput over the optimiser steps alone, and the time it has left."""

from __future__ import annotations

import pytest
import torch

from gns_framework.runtime.processes import Processes
from gns_framework.training import progress
from gns_framework.training.progress import Deadline, Throughput, time_to_go


def test_time_to_go_reads_like_a_clock():
    assert time_to_go(100, 40000, 100, 43.3) == "step 100 of 40000, 2.31 steps/s: about 4 h 48 min to go"
    assert time_to_go(900, 1000, 900, 90.0) == "step 900 of 1000, 10 steps/s: about 1 min to go"
    assert time_to_go(5, 10, 0, 0.0) == "step 5 of 10"


def test_throughput_counts_steps_and_particles_between_reads_and_leaves_out_pauses(monkeypatch):
    clock = iter([0.0, 2.0, 10.0, 11.0, 12.0])  # start, first read; start, restart after a pause, second read
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    synced = []
    monkeypatch.setattr(progress, "synchronize", lambda device: synced.append(device.type))
    throughput = Throughput(torch.device("cpu"))
    for particles in (100, 300):
        throughput.step_starts()  # the clock starts at the first step only
        throughput.step_done(particles)
    assert throughput.read() == {"steps_per_s": 1.0, "particles_per_s": 200.0}
    throughput.step_starts()
    throughput.pause()  # validation: the step's time up to here is not counted, the step is
    throughput.step_starts()
    throughput.step_done(50)
    assert throughput.read() == {"steps_per_s": 1.0, "particles_per_s": 50.0}
    assert synced == ["cpu"] * 5  # every window starts and ends on a synchronised device


def test_throughput_is_read_after_a_step_only():
    with pytest.raises(AssertionError, match="read after a step"):
        Throughput(torch.device("cpu")).read()


def test_a_deadline_alone_looks_at_its_clock_after_every_step(monkeypatch):
    assert not Deadline(None, Processes()).passed(logs=True)
    clock = iter([0.0, 50.0, 99.0, 100.0])
    monkeypatch.setattr(Deadline, "clock", staticmethod(lambda: next(clock)))
    deadline = Deadline(100.0, Processes())
    assert [deadline.passed(logs=False), deadline.passed(logs=False), deadline.passed(logs=False)] == [
        False,
        False,
        True,
    ]
    assert deadline.reached


def test_processes_agree_on_the_deadline_at_logging_steps_by_rank_zeros_clock(monkeypatch):
    class Two(Processes):
        def broadcast(self, value):
            told.append(value)
            return True  # rank 0's verdict, whatever this process's clock says

    told: list = []
    clock = iter([0.0, 10.0, 20.0])
    monkeypatch.setattr(Deadline, "clock", staticmethod(lambda: next(clock)))
    deadline = Deadline(100.0, Two(rank=1, world_size=2))
    assert not deadline.passed(logs=False) and told == []  # not a logging step: no look, no collective
    assert deadline.passed(logs=True) and told == [False]
