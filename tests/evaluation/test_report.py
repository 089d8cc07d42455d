"""The error-against-run-time report on a toy ground-truth simulator and a fake learned model."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from PIL import Image

from gns_framework.data.trajectory import Trajectory
from gns_framework.evaluation.report import Candidate, Prediction, case_range, evaluate, score_rollout, write_report
from gns_framework.hookspecs import hookimpl
from gns_framework.io.rollout_file import load_rollout
from gns_framework.plugin_types import Metric
from gns_framework.plugins import load_registry
from gns_framework.safe_names import safe_component

GRAVITY = np.array([0.0, -9.81])
HISTORY, STEPS, DT = 6, 12, 0.01
SAND = 6


def falling_sand(start: np.ndarray, velocity: np.ndarray, substeps: int) -> np.ndarray:
    """Semi-implicit Euler with ``substeps`` per frame; particles stop on the floor y = 0.

    Returns (HISTORY + STEPS, N, 2) frames: the finer the substeps, the closer to the
    reference, as for a real solver's time step.
    """
    h = DT / substeps
    position, velocity = start.copy(), velocity.copy()
    frames = [position.copy()]
    for _ in range(HISTORY + STEPS - 1):
        for _ in range(substeps):
            velocity = velocity + h * GRAVITY
            position = position + h * velocity
            landed = position[:, 1] < 0
            position[landed, 1] = 0.0
            velocity[landed] = 0.0
        frames.append(position.copy())
    return np.stack(frames)


@pytest.fixture
def scenes(make_metadata):
    """Two test cases made by the reference setting (16 substeps), with their initial states and metadata."""
    metadata = make_metadata(dim=2, dt=DT)
    states, cases = {}, []
    for seed in range(2):
        rng = np.random.default_rng(seed)
        start = np.column_stack([rng.uniform(0.2, 0.4, 40), rng.uniform(0.2, 0.6, 40)])
        velocity = np.column_stack([rng.uniform(0.5, 1.5, 40), np.zeros(40)])
        frames = falling_sand(start, velocity, substeps=16)
        key = f"case{seed}"
        states[key] = (start, velocity)
        cases.append(Trajectory(frames, np.full(40, SAND), key=key))
    return states, cases, metadata


def simulator(states, substeps: int, every_other_particle: bool = False):
    def simulate(case: Trajectory) -> Prediction:
        start, velocity = states[case.key]
        if every_other_particle:
            start, velocity = start[::2], velocity[::2]
        frames = falling_sand(start, velocity, substeps)
        if not every_other_particle:
            return Prediction(frames[HISTORY:])
        return Prediction(frames[HISTORY:], np.full(len(start), SAND), frames[HISTORY - 1])

    return simulate


def learned(case: Trajectory) -> Prediction:
    """A model's rollout, as a tensor like a model returns it, drifting 0.002 L per step."""
    drift = 0.002 * np.arange(1, STEPS + 1)[:, None, None]
    return Prediction(torch.as_tensor(case.position[HISTORY:] + drift, dtype=torch.float32))


class WorkClock:
    """A clock that only the simulations move: each adds the seconds it is said to cost."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def costing(self, seconds: float, simulate):
        def run(case):
            self.now += seconds
            return simulate(case)

        return run


COSTS = {"mpm dt/16": 1.6, "mpm dt/2": 0.2, "mpm dt/1": 0.1, "mpm coarse": 0.8, "gns": 0.05}
"""Seconds per rollout on the work clock: the simulator's in proportion to its substeps and particles."""


def candidates(states, clock: WorkClock | None = None):
    clock = clock or WorkClock()
    simulations = {
        "mpm dt/16": ("simulator", simulator(states, 16), "16 substeps"),
        "mpm dt/2": ("simulator", simulator(states, 2), "2 substeps"),
        "mpm dt/1": ("simulator", simulator(states, 1), "1 substep"),
        "mpm coarse": ("simulator", simulator(states, 16, every_other_particle=True), "half the particles"),
        "gns": ("learned", learned, "model.pt"),
    }
    return [
        Candidate(name, kind, clock.costing(COSTS[name], simulate), reference=name == "mpm dt/16", settings=settings)
        for name, (kind, simulate, settings) in simulations.items()
    ]


@pytest.fixture
def report(scenes, tmp_path):
    states, cases, metadata = scenes
    clock = WorkClock()
    return evaluate(
        candidates(states, clock),
        cases,
        metadata,
        HISTORY,
        repeats=2,
        warmup=1,
        granular_types={SAND},
        material_names={SAND: "sand"},
        rollout_dir=tmp_path / "rollouts",
        clock=clock,
    )


def test_entries_hold_speedup_and_error_against_the_reference(report):
    by_name = {e.name: e for e in report.entries}
    reference = by_name["mpm dt/16"]
    assert reference.speedup == pytest.approx(1.0)
    assert reference.metrics["mse_full"] == 0.0 and reference.metrics["sinkhorn_final_pct"] == pytest.approx(
        0, abs=1e-3
    )
    for entry in report.entries:
        assert entry.seconds == pytest.approx(COSTS[entry.name])  # the median rollout, warm-up excluded
        assert entry.speedup == pytest.approx(COSTS["mpm dt/16"] / COSTS[entry.name])
    # A coarser time step is less accurate.
    assert by_name["mpm dt/1"].metrics["mse_full"] > by_name["mpm dt/2"].metrics["mse_full"] > 0
    # The learned model drifts 0.002 L per step in both components: MSE at step k is (0.002 k)^2.
    assert by_name["gns"].metrics["mse_1"] == pytest.approx(0.002**2, rel=1e-4)
    assert by_name["gns"].metrics["mse_full[sand]"] == pytest.approx(by_name["gns"].metrics["mse_full"])
    assert by_name["gns"].metrics["mse_20"] is None
    # Another resolution has no particle correspondence: no MSE, but a Sinkhorn error.
    assert by_name["mpm coarse"].metrics["mse_full"] is None and by_name["mpm coarse"].mse_per_step is None
    assert by_name["mpm coarse"].metrics["sinkhorn_final_pct"] > 0
    assert by_name["gns"].metrics["runout_error"] is not None
    assert report.num_cases == 2 and report.hardware["torch_threads"] >= 1


def test_report_files(report, tmp_path):
    paths = write_report(report, tmp_path / "report")
    markdown = paths["markdown"].read_text()
    assert "torch threads" in markdown and "median of 2 repeats" in markdown
    assert "| mpm dt/16 (reference) | simulator |" in markdown
    assert "speed-up vs mpm dt/16" in markdown
    with paths["csv"].open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["name"] for r in rows] == [e.name for e in report.entries]
    gns = next(r for r in rows if r["name"] == "gns")
    assert gns["mse_50"] == "" and float(gns["mse_1"]) == pytest.approx(0.002**2, rel=1e-4)
    assert float(gns["speedup"]) > 0 and gns["mse_full[sand]"] != ""
    for plot in ("error_vs_time", "error_over_rollout"):
        with Image.open(paths[plot]) as image:
            assert image.format == "PNG" and image.size[0] > 300


def test_each_case_is_reported_and_the_spread_stated(report, tmp_path):
    paths = write_report(report, tmp_path / "report")
    with paths["cases_csv"].open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["name"], r["case"]) for r in rows] == [(e.name, k) for e in report.entries for k in ("case0", "case1")]
    gns = next(e for e in report.entries if e.name == "gns")
    per_case = [float(r["runout_error_pct"]) for r in rows if r["name"] == "gns"]
    assert per_case == pytest.approx([gns.cases[k]["runout_error_pct"] for k in ("case0", "case1")])
    assert np.mean(per_case) == pytest.approx(gns.metrics["runout_error_pct"])
    line = next(text for text in paths["markdown"].read_text().splitlines() if text.startswith("- gns:"))
    worst = max(per_case)
    assert f"runout_error_pct {np.median(per_case):.3g} / {worst:.3g}" in line
    # The error-vs-time plot's bars run over the same cases.
    assert case_range(gns, "runout_error_pct") == pytest.approx((min(per_case), max(per_case)))
    assert case_range(gns, "no such metric") is None


def test_rollouts_of_the_same_particles_are_saved_for_rendering(report, tmp_path):
    """One folder per candidate, one file per case, each a safe file name: ``mpm dt/16`` is no sub-folder ``16``."""
    saved = sorted(p.relative_to(tmp_path / "rollouts").as_posix() for p in (tmp_path / "rollouts").rglob("*.npz"))
    same_particles = ["gns", "mpm dt/1", "mpm dt/16", "mpm dt/2"]
    assert saved == sorted(f"{safe_component(name)}/case{k}.npz" for name in same_particles for k in range(2))
    assert all(part.count("/") == 1 for part in saved) and "mpm_dt_16-" in "".join(saved)
    by_name = {e.name: e for e in report.entries}
    assert by_name["gns"].rollout_files == tuple(tmp_path / "rollouts" / "gns" / f"case{k}.npz" for k in range(2))
    assert by_name["mpm coarse"].rollout_files == (None, None)
    rollout = load_rollout(by_name["gns"].rollout_files[1])
    assert rollout.num_steps == STEPS and rollout.initial_positions.shape == (HISTORY, 40, 2)


def test_invalid_candidate_lists_are_refused(scenes):
    states, cases, metadata = scenes
    twice = [candidates(states)[0], Candidate("other", "simulator", simulator(states, 2), reference=True)]
    with pytest.raises(ValueError, match="at most one reference"):
        evaluate(twice, cases, metadata, HISTORY)
    with pytest.raises(ValueError, match="unique"):
        evaluate([candidates(states)[4]] * 2, cases, metadata, HISTORY)
    with pytest.raises(ValueError, match="unknown error_metric"):
        evaluate(candidates(states)[4:], cases, metadata, HISTORY, error_metric="accuracy")
    short = Candidate("short", "learned", lambda case: Prediction(case.position[HISTORY : HISTORY + 3]))
    with pytest.raises(ValueError, match="S = 12 frames"):
        evaluate([short], cases, metadata, HISTORY)


def test_score_rollout_file(make_rollout):
    # The fixture's prediction is off by 0.001 k in every component at step k (kinematic particles exact).
    summary = score_rollout(make_rollout(steps=8), granular_types={SAND}, material_names={SAND: "sand"})
    assert summary["mse_1"] == pytest.approx(1e-6, rel=1e-3)
    assert summary["mse_5"] == pytest.approx(1e-6 * (1 + 4 + 9 + 16 + 25) / 5, rel=1e-3)
    assert summary["mse_10"] is None
    assert summary["mse_full[sand]"] == pytest.approx(summary["mse_full"])
    assert summary["runout_error"] is not None and summary["diverged"] == 0.0


def test_a_plugin_metric_is_measured_beside_the_builtins(make_rollout):
    moved = Metric(
        "moving_particles", "1, particles the errors are taken over", lambda pair: pair.target.moving.sum(-1).double()
    )

    class MetricPlugin:
        @staticmethod
        @hookimpl
        def gns_metrics():
            return [moved]

    registry = load_registry(plugins=[("count-metric", MetricPlugin)])
    names = [m.name for m in registry.metrics()]
    assert names[-1] == "moving_particles" and "sinkhorn_final" in names
    summary = score_rollout(make_rollout(steps=8, particles=12), metrics=registry.metrics())
    assert summary["moving_particles"] == 10  # two of the twelve are kinematic
    assert summary["sinkhorn_final"] is not None


def test_a_batched_candidate_is_charged_its_share_of_each_batch(scenes):
    """Two cases rolled out together in 0.06 s each cost 0.03 s; the batch sees both cases, in order."""
    _states, cases, metadata = scenes
    clock, batches = WorkClock(), []

    def simulate_batch(chunk):
        batches.append([case.key for case in chunk])
        clock.now += 0.06
        return [learned(case) for case in chunk]

    one_at_a_time = Candidate("gns", "learned", clock.costing(0.05, learned))
    batched = Candidate("gns [batch 2]", "learned", learned, simulate_batch=simulate_batch, batch=2)
    report = evaluate([one_at_a_time, batched], cases, metadata, HISTORY, repeats=2, warmup=1, clock=clock)
    by_name = {e.name: e for e in report.entries}
    assert by_name["gns"].seconds == pytest.approx(0.05)
    assert by_name["gns [batch 2]"].seconds == pytest.approx(0.03)
    assert batches == [["case0", "case1"]] * 3, "one warm-up and two timed calls, each with both cases"
    assert by_name["gns [batch 2]"].metrics == pytest.approx(by_name["gns"].metrics)


def test_the_particles_a_wall_held_are_counted_per_case_and_stated(scenes, tmp_path):
    """A learned rollout's held particles go into cases.csv per case and into report.md per model (issue 46)."""
    import dataclasses

    _states, cases, metadata = scenes
    held = {"case0": 0, "case1": 7}

    def guarded(case):
        return dataclasses.replace(learned(case), held=held[case.key])

    quiet = Candidate("quiet", "learned", learned)
    report = evaluate([Candidate("gns", "learned", guarded), quiet], cases, metadata, HISTORY, repeats=1, warmup=0)
    by_name = {e.name: e for e in report.entries}
    assert [c["wall_held_particles"] for c in by_name["gns"].cases.values()] == [0.0, 7.0]
    assert all("wall_held_particles" not in c for c in by_name["quiet"].cases.values())
    paths = write_report(report, tmp_path)
    text = paths["markdown"].read_text()
    assert (
        "- gns: 7 particle(s) in 1 of 2 case(s), at most 7 in one" in text and "- quiet:" not in text.split("held")[-1]
    )
    rows = list(csv.DictReader(paths["cases_csv"].open()))
    assert [r["wall_held_particles"] for r in rows if r["name"] == "gns"] == ["0.0", "7.0"]


def test_progress_is_reported_after_each_candidate_and_case(scenes):
    """The report phase says what it is timing: every candidate's every case, counted over all of them."""
    _states, cases, metadata = scenes
    seen = []
    evaluate(
        [Candidate("gns", "learned", learned), Candidate("other", "learned", learned)],
        cases,
        metadata,
        HISTORY,
        repeats=1,
        warmup=0,
        progress=lambda *call: seen.append(call),
    )
    assert seen == [("gns", 1, 4), ("gns", 2, 4), ("other", 3, 4), ("other", 4, 4)]
