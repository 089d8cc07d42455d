"""A small hand-made report for the tests of the report's tables, plots and files."""

from __future__ import annotations

import numpy as np

from gns_framework.evaluation.records import WALL_HELD, Entry, Report


def entry(name: str, reference: bool = False, seconds: float = 2.0, held: tuple[int, ...] = (0, 0)) -> Entry:
    cases = {
        f"case{k}": {"mse_20": 0.01 * (k + 1), "runout_error_pct": 5.0 * (k + 1), "sinkhorn_final_pct": 1.0 + k}
        for k in range(2)
    }
    for case, count in zip(cases.values(), held, strict=True):
        case[WALL_HELD] = float(count)
    return Entry(
        name=name,
        kind="simulator" if reference else "learned",
        settings="grid 96" if reference else "step 1000",
        device="cpu",
        reference=reference,
        seconds=seconds,
        spread=0.1,
        metrics={"mse_20": 0.015, "runout_error_pct": 7.5, "mse_1": None},
        mse_per_step=None if reference else np.array([1e-6, 2e-6, np.nan, 4e-6]),
        speedup=None if reference else 4.0,
        cases=cases,
    )


def report(held: tuple[int, ...] = (0, 0)) -> Report:
    return Report(
        entries=[entry("mpm", reference=True, seconds=8.0), entry("model", held=held)],
        error_metric="runout_error_pct",
        num_cases=2,
        repeats=3,
        warmup=1,
        dt=0.01,
        hardware={
            "cpu": "test CPU",
            "cpu_cores_usable": 1,
            "cpu_cores_total": 2,
            "torch_threads": 1,
            "torch": "2.13.0",
            "device": "cpu",
        },
        metric_units={"mse_20": "L^2, position MSE at step 20"},
    )
