"""The stability report: sections produce rows with outcomes, and a failing row is recognised."""

from __future__ import annotations

import pytest
import torch

from gns_framework.plugins import load_registry
from gns_framework.stability.report import Row, chain_limits, failed, format_row, rollout_guard, run_report

pytestmark = pytest.mark.stability
torch.set_num_threads(1)


def test_chain_limit_and_guard_sections_pass():
    rows = list(run_report(load_registry(), sections=(chain_limits, rollout_guard)))
    assert [row.case for row in rows[:3]] == ["semi_implicit_euler", "velocity_verlet", "explicit_euler"]
    assert [row.outcome for row in rows[:2]] == ["limit as theory"] * 2
    assert [row.outcome.split()[0] for row in rows[3:]] == ["stopped", "clamped", "stopped", "clamped"]
    assert not any(failed(row) for row in rows)


def test_failures_are_recognised_and_every_column_printed():
    row = Row("g", "c", "NaN/Inf in second order", "figures")
    assert failed(row) and not failed(Row("g", "c", "finite", ""))
    assert format_row(row).split() == ["g", "c", "NaN/Inf", "in", "second", "order", "figures"]
