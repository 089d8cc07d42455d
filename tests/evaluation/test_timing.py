"""Timing: warm-up runs are not timed, the median of the repeats is reported."""

from __future__ import annotations

import pytest

from gns_framework.evaluation.timing import Timing, format_hardware, hardware_description, time_call


class ScriptedClock:
    """A clock that each call of the work advances by the next of ``durations`` seconds."""

    def __init__(self, durations):
        self.now, self.durations = 100.0, iter(durations)

    def __call__(self) -> float:
        return self.now

    def work(self) -> float:
        self.now += next(self.durations)
        return self.now


def test_warmup_runs_are_excluded_and_median_taken():
    clock = ScriptedClock([5.0, 0.25, 2.0, 0.5])
    result, timing = time_call(clock.work, repeats=3, warmup=1, clock=clock)
    assert result == 107.75  # the last timed call's result
    # The slow first call was the warm-up: the repeats took 0.25, 2 and 0.5 s.
    assert timing.seconds == (0.25, 2.0, 0.5) and timing.warmup == 1
    assert timing.median == 0.5 and timing.spread == 1.75


def test_timing_median_and_bad_arguments():
    assert Timing((3.0, 1.0, 2.0), warmup=0).median == 2.0
    with pytest.raises(ValueError):
        time_call(lambda: None, repeats=0)


def test_hardware_description_names_cpu_cores_and_threads():
    description = hardware_description()
    assert description["cpu"] and description["cpu_cores_usable"] >= 1 and description["torch_threads"] >= 1
    line = format_hardware(description)
    assert f"{description['torch_threads']} torch threads" in line and "device cpu" in line
