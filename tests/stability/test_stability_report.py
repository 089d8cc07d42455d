"""The stability report: every section runs and passes on the built-in components, and every failing
outcome (a symplectic integrator that diverges or gains energy, non-finite predictions, a guard that
neither stops nor clamps) is marked failing and makes ``gns stability`` exit 1."""

from __future__ import annotations

import functools
import math

import pytest
import torch

from gns_framework.cli import main
from gns_framework.model.rollout_guard import RolloutGuard
from gns_framework.plugins import load_registry
from gns_framework.stability import report
from gns_framework.stability.extreme import tiny_simulator
from gns_framework.stability.report import Row, chain_drift, chain_limits, format_row, near_collision, rollout_guard

pytestmark = [pytest.mark.stability, pytest.mark.usefixtures("one_torch_thread")]

GROUPS = {
    report.chain_limits: "spring chain N=32 k=1e6: dt limit",
    report.chain_drift: "spring chain: 10000 steps",
    report.near_collision: "near-collision",
    report.extreme_inputs: "learned simulator",
    report.rollout_guard: "rollout guard",
}
"""The start of each section's group names."""


class SwappedIntegrators:
    """The installed components, with integrators answering to another's name and claiming its facts
    (an unstable 'velocity_verlet' that says it is symplectic)."""

    def __init__(self, swaps: dict[str, str]):
        self.registry, self.swaps = load_registry(), swaps

    def entries(self, kind: str):
        return self.registry.entries(kind)

    def get(self, kind: str, name: str) -> type:
        if kind != "integrator" or name not in self.swaps:
            return self.registry.get(kind, name)
        claimed = self.registry.get(kind, name)
        facts = {"name": name, "symplectic": claimed.symplectic, "stability_bound": claimed.stability_bound}
        return type(f"Claiming{claimed.__name__}", (self.registry.get(kind, self.swaps[name]),), facts)


class BlindGuard(RolloutGuard):
    """A guard that sees nothing: never stops, never clamps."""

    def check(self, step, position, previous, trajectory=""):
        return position, []


def test_every_section_of_the_full_report_passes_and_gns_stability_exits_0(capsys):
    assert set(GROUPS) == set(report.SECTIONS)
    assert main(["stability"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:4] == ["group", "case", "outcome", "figures"]
    body = [line for line in lines[1:] if line and not line.startswith("0 failing")]
    for section, group in GROUPS.items():
        assert any(line.startswith(group) for line in body), section.__name__
    assert not any("FAIL" in line for line in lines)
    assert "0 failing case(s)" in lines[-1]
    outcomes = " ".join(body)
    for expected in (
        "limit as theory",
        "unstable for every dt",
        "bounded, no drift",
        "energy grows",
        "diverged",
        "tunnels at 30/omega",
        "stopped at step 0",
        "clamped 5x, output finite",
        "14/14 finite",
    ):
        assert expected in outcomes  # explicit Euler's growth is expected, not a failure


def test_a_symplectic_integrator_that_gains_energy_fails_every_integrator_section(monkeypatch, capsys):
    registry = SwappedIntegrators({"velocity_verlet": "explicit_euler"})
    rows = [row for section in (chain_limits, chain_drift, near_collision) for row in section(registry)]
    verlet = [row for row in rows if row.case == "velocity_verlet"]
    assert [row.failing for row in verlet] == [True] * 4
    assert [row.outcome for row in verlet[1:]] == ["energy grows", "diverged", "energy error over 1% at 0.1/omega"]
    assert not any(row.failing for row in rows if row.case != "velocity_verlet")

    monkeypatch.setattr("gns_framework.cli.stability.load_registry", lambda: registry)
    monkeypatch.setattr(
        "gns_framework.cli.stability.run_report", functools.partial(report.run_report, sections=(chain_drift,))
    )
    assert main(["stability"]) == 1
    out = capsys.readouterr().out
    assert "2 failing case(s)" in out
    assert "FAIL: spring chain: 10000 steps, omega_max dt = 1.0: velocity_verlet: diverged" in out


def test_non_finite_predictions_fail_their_rows_and_the_processor_summary(monkeypatch):
    simulator = tiny_simulator(load_registry(), 2)
    simulator.output_stats.mean.fill_(math.nan)
    row = report._extreme_row(simulator, "single particle", 2, torch.float32, "interaction_network")
    assert row.failing and row.outcome.startswith("NaN/Inf in")

    def sabotaged(registry, dim, processor="interaction_network", zero_std=False, seed=0):
        simulator = tiny_simulator(registry, dim, processor, zero_std, seed)
        simulator.output_stats.mean.fill_(math.nan)
        return simulator

    monkeypatch.setattr(report, "tiny_simulator", sabotaged)
    monkeypatch.setattr(report, "other_processors", lambda registry: ["egnn"])
    summary = [row for row in report.extreme_inputs(load_registry()) if row.group == "learned simulator, egnn"]
    assert summary[0].failing and summary[0].outcome == "0/14 finite"


def test_a_guard_that_neither_stops_nor_clamps_fails(monkeypatch):
    monkeypatch.setattr(report, "RolloutGuard", BlindGuard)
    rows = list(rollout_guard(load_registry()))
    assert len(rows) == 4 and all(row.failing for row in rows)
    assert rows[0].outcome.startswith("not stopped")


def test_failing_rows_are_marked_and_every_column_printed():
    row = Row("g", "c", "energy grows", "figures", failing=True)
    assert format_row(row).split() == ["g", "c", "FAIL:", "energy", "grows", "figures"]
    assert format_row(Row("g", "c", "finite", "")).split() == ["g", "c", "finite"]


class OnlyIntegrator(SwappedIntegrators):
    """The installed components with a single integrator, so its row is the first the report computes."""

    def __init__(self, name: str):
        super().__init__({})
        self.only = name

    def entries(self, kind: str):
        entries = self.registry.entries(kind)
        return [e for e in entries if e.name == self.only] if kind == "integrator" else entries


def test_an_integrator_without_a_stability_bound_is_searched_on_its_own():
    """Its dt search needs no bounded integrator computed before it (each row stands alone)."""
    (row,) = chain_limits(OnlyIntegrator("explicit_euler"))
    assert row.case == "explicit_euler" and not row.failing
    assert row.outcome == "unstable for every dt" and "one-mode bound" in row.figures
