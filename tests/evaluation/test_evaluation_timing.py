"""Timing: warm-up runs are not timed, the median of the repeats is reported."""

from __future__ import annotations

import time

import pytest

from gns_framework.evaluation.timing import Timing, format_hardware, hardware_description, time_call


def test_warmup_runs_are_excluded_and_median_taken():
    durations = iter([0.05, 0.0, 0.02, 0.0])
    calls = []

    def work():
        calls.append(1)
        time.sleep(next(durations))
        return len(calls)

    result, timing = time_call(work, repeats=3, warmup=1)
    assert len(calls) == 4 and result == 4
    assert len(timing.seconds) == 3 and timing.warmup == 1
    # The slow first call was the warm-up: the repeats took ~0, 0.02, ~0 s.
    assert timing.median < 0.015
    assert timing.spread >= 0.015


def test_timing_median_and_bad_arguments():
    assert Timing((3.0, 1.0, 2.0), warmup=0).median == 2.0
    with pytest.raises(ValueError):
        time_call(lambda: None, repeats=0)


def test_hardware_description_names_cpu_cores_and_threads():
    description = hardware_description()
    assert description["cpu"] and description["cpu_cores_usable"] >= 1 and description["torch_threads"] >= 1
    line = format_hardware(description)
    assert f"{description['torch_threads']} torch threads" in line and "device cpu" in line
