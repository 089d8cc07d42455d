"""Error against run time: roll every candidate out on the test cases, time it, score it, report.

A test case is a trajectory of the test split: its first C frames are the input,
the rest the truth to predict. A candidate is anything that turns a test case's
input frames into a rollout: a learned model from a checkpoint, or the
ground-truth simulator run at some resolution or time step. One simulator
setting is the *reference* (the one that made the test data); speed-ups are its
run time over each candidate's.

The report is a Markdown and a CSV table plus two PNG plots (error against run
time, log-log; position error over rollout time). matplotlib is imported only
when the plots are drawn.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np
import torch

from ..data.metadata import DatasetMetadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..io.rollout_file import save_rollout
from ..plugin_types import Metric
from ..runtime.device import is_cuda
from ..safe_names import ensure_inside, unique_components
from .metrics import DEFAULT_HORIZONS, ParticleRollout, RolloutPair, metric_units, rollout_metrics, summarise
from .plots import case_range, plot_error_over_rollout, plot_error_vs_time
from .records import WALL_HELD, WARNING_ERROR, WARNING_FLAG, WARNING_SCORE, Candidate, Entry, Kind, Prediction, Report
from .report_files import write_report
from .tables import markdown_table, write_cases_csv, write_csv
from .timing import Timing, hardware_description, time_call

__all__ = [
    "WALL_HELD",
    "Candidate",
    "Entry",
    "Kind",
    "Prediction",
    "Report",
    "ScoreOptions",
    "case_range",
    "evaluate",
    "installed",
    "markdown_table",
    "plot_error_over_rollout",
    "plot_error_vs_time",
    "score_prediction",
    "score_rollout",
    "write_cases_csv",
    "write_csv",
    "write_report",
]


def evaluate(
    candidates: Sequence[Candidate],
    cases: Sequence[Trajectory],
    metadata: DatasetMetadata,
    history: int,
    *,
    repeats: int = 3,
    warmup: int = 1,
    error_metric: str = "sinkhorn_final_pct",
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    granular_types: Collection[int] = (),
    material_names: Mapping[int, str] | None = None,
    kinematic_types: Collection[int] | None = None,
    metrics: Sequence[Metric] | None = None,
    rollout_dir: str | Path | None = None,
    clock: Callable[[], float] = time.perf_counter,
    progress: Callable[[str, int, int], None] | None = None,
) -> Report:
    """Roll every candidate out on every case, timing each rollout and scoring it.

    Args:
        candidates: learned models and simulator settings; at most one is the reference.
        cases: the test split.
        metadata: the dataset's metadata (bounds, dt, ...).
        history: C, the input frames of every case; the candidates predict the rest.
        repeats, warmup: timed and untimed runs per case (the median of the timed ones counts).
        error_metric: the metric shown as "error" and plotted against run time.
        horizons, granular_types, material_names: passed to :func:`rollout_metrics`.
        kinematic_types, metrics: as in :func:`score_prediction`.
        rollout_dir: when given, every rollout that predicts the case's own particles is
            written there as ``<candidate>/<case>.npz`` (for ``gns render``), both names made
            safe file names, unique in their folder (:mod:`gns_framework.safe_names`); the
            entries' ``rollout_files`` say where.
        clock: the timings' clock, seconds (tests give one that runs with the work, not the wall).
        progress: called as ``progress(candidate name, cases done, cases in all)`` after each
            candidate's case is timed and scored (all candidates' cases counted together).
    """
    if not candidates or not cases:
        raise ValueError("evaluate needs at least one candidate and one case")
    kinematic_types, metrics = installed(kinematic_types, metrics)
    references = [c.name for c in candidates if c.reference]
    if len(references) > 1:
        raise ValueError(f"at most one reference simulator, got {references}")
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        raise ValueError(f"candidate names must be unique, got {names}")
    known = {m.name for m in metrics} | {f"mse_{h}" for h in horizons}
    if error_metric not in known:
        raise ValueError(f"unknown error_metric {error_metric!r}; choose one of {sorted(known)}")

    # Names from the data and the labels are never paths: one safe file name each, unique in its folder.
    folders = dict(zip(names, unique_components(names), strict=True))
    files = [f"{name}.npz" for name in unique_components([case.key for case in cases])]
    entries = []
    done, total = 0, len(candidates) * len(cases)
    for candidate in candidates:
        summaries, timings, curves, written = [], [], [], []
        for case, file_name, prediction, timing in _timed_rollouts(candidate, cases, files, repeats, warmup, clock):
            scores = score_prediction(
                prediction,
                case,
                history,
                metadata,
                horizons,
                granular_types,
                material_names,
                kinematic_types=kinematic_types,
                metrics=metrics,
            )
            summary = summarise(scores)
            summary["seconds_per_rollout"] = timing.median  # per case: time against scene size
            if prediction.held is not None:
                summary[WALL_HELD] = float(prediction.held)
            warned = candidate.warn(case, prediction) if candidate.warn is not None else None
            if warned is not None:
                summary[WARNING_SCORE], summary[WARNING_FLAG] = warned.score, float(warned.flagged)
                summary[WARNING_ERROR] = warned.error_pct
            summaries.append(summary)
            timings.append(timing)
            curves.append(None if scores["mse_per_step"] is None else scores["mse_per_step"][0].numpy())
            path = None
            if rollout_dir is not None and _same_particles(prediction, case, history):
                path = ensure_inside(Path(rollout_dir) / folders[candidate.name] / file_name, rollout_dir)
                save_rollout(path, _as_rollout(prediction, case, history, metadata))
            written.append(path)
            done += 1
            if progress is not None:
                progress(candidate.name, done, total)
        entries.append(_entry(candidate, summaries, timings, curves, [case.key for case in cases], written))

    reference = next((e for e in entries if e.reference), None)
    if reference is not None:
        entries = [_with_speedup(e, reference.seconds) for e in entries]
    gpu = next((c.device for c in candidates if is_cuda(c.device)), None)
    return Report(
        entries,
        error_metric,
        len(cases),
        repeats,
        warmup,
        metadata.dt,
        hardware_description(gpu),
        metric_units(metrics),
    )


def _timed_rollouts(
    candidate: Candidate,
    cases: Sequence[Trajectory],
    files: Sequence[str],
    repeats: int,
    warmup: int,
    clock: Callable[[], float],
) -> Iterator[tuple[Trajectory, str, Prediction, Timing]]:
    """Each case with its file name, the candidate's rollout of it and the time that rollout is charged.

    One at a time, each case's own timing; batched, the cases go ``candidate.batch``
    at a time and each is charged an equal share of its batch's time.
    """
    if candidate.simulate_batch is None or candidate.batch < 2:
        for case, file_name in zip(cases, files, strict=True):
            prediction, timing = time_call(
                partial(candidate.simulate, case), repeats=repeats, warmup=warmup, device=candidate.device, clock=clock
            )
            yield case, file_name, prediction, timing
        return
    for start in range(0, len(cases), candidate.batch):
        chunk = list(cases[start : start + candidate.batch])
        predictions, timing = time_call(
            partial(candidate.simulate_batch, chunk),
            repeats=repeats,
            warmup=warmup,
            device=candidate.device,
            clock=clock,
        )
        share = Timing(tuple(seconds / len(chunk) for seconds in timing.seconds), timing.warmup)
        yield from (
            (case, file, prediction, share)
            for case, file, prediction in zip(chunk, files[start : start + len(chunk)], predictions, strict=True)
        )


class ScoreOptions(TypedDict, total=False):
    """What :func:`score_prediction` measures and leaves out, beyond the prediction and its case."""

    horizons: Sequence[int]
    granular_types: Collection[int]
    material_names: Mapping[int, str] | None
    kinematic_types: Collection[int] | None
    metrics: Sequence[Metric] | None


def score_rollout(rollout: Rollout, **options: Unpack[ScoreOptions]) -> dict[str, float | None]:
    """Every metric of a rollout's prediction against its ground truth (no timing); it needs its metadata.

    ``options`` as :func:`score_prediction`'s."""
    if rollout.metadata is None:
        raise ValueError(f"{rollout.source}: scoring a rollout needs the dataset's metadata; the rollout has none")
    prediction = Prediction(rollout.predicted)
    return summarise(score_prediction(prediction, rollout.truth, rollout.history, rollout.metadata, **options))


def installed(
    kinematic_types: Collection[int] | None, metrics: Sequence[Metric] | None
) -> tuple[Collection[int], Sequence[Metric]]:
    """``kinematic_types`` and ``metrics``, each that of the installed plugins where None."""
    if kinematic_types is not None and metrics is not None:
        return kinematic_types, metrics
    from ..plugins import load_registry

    registry = load_registry()
    return (
        registry.kinematic_types() if kinematic_types is None else kinematic_types,
        registry.metrics() if metrics is None else metrics,
    )


def _host_float64(values: np.ndarray | torch.Tensor) -> torch.Tensor:
    """A prediction on any device, as a float64 CPU tensor (metrics in double precision)."""
    return torch.as_tensor(values).detach().to("cpu", torch.float64)


def _same_particles(prediction: Prediction, case: Trajectory, history: int) -> bool:
    return prediction.particle_type is None and np.shape(prediction.position) == case.position[history:].shape


def score_prediction(
    prediction: Prediction,
    case: Trajectory,
    history: int,
    metadata: DatasetMetadata,
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    granular_types: Collection[int] = (),
    material_names: Mapping[int, str] | None = None,
    *,
    kinematic_types: Collection[int] | None = None,
    metrics: Sequence[Metric] | None = None,
) -> dict[str, torch.Tensor | None]:
    """Every metric of ``metrics`` for one prediction against its case's ground truth, in float64.

    The case's first ``history`` frames are the input, the rest the truth; ``metadata``
    gives the frames' time step and the domain's bounds, where the case has no box of its own.
    ``kinematic_types``: particle types left out of every error (the scene's
    ``kinematic_types``); ``metrics``: what is measured. None: those of the installed
    plugins (:meth:`~gns_framework.plugins.Registry.kinematic_types`, ``.metrics``).
    """
    kinematic_types, metrics = installed(kinematic_types, metrics)
    position = _host_float64(prediction.position)
    ground_truth, last_input = case.position[history:], case.position[history - 1]
    if position.ndim != 3 or position.shape[0] != ground_truth.shape[0]:
        raise ValueError(
            f"case {case.key!r}: prediction must be (S, N, d) with S = {ground_truth.shape[0]} frames, "
            f"got {tuple(position.shape)}"
        )
    particle_type = case.particle_type if prediction.particle_type is None else prediction.particle_type
    start = last_input if prediction.start is None else prediction.start
    predicted = ParticleRollout.of(
        position, torch.as_tensor(particle_type), start=_host_float64(start), kinematic_types=kinematic_types
    )
    target = ParticleRollout.of(
        torch.as_tensor(ground_truth, dtype=torch.float64),
        torch.as_tensor(case.particle_type),
        start=torch.as_tensor(last_input, dtype=torch.float64),
        kinematic_types=kinematic_types,
    )
    pair = RolloutPair(
        predicted,
        target,
        dt=metadata.dt,
        # A case drawn in a box of its own (the general sand scenes) is measured in it: its walls, its size.
        bounds=case.bounds.tolist() if case.bounds is not None else metadata.bounds,
        same_particles=prediction.particle_type is None,
        horizons=horizons,
        granular_types=granular_types,
        material_names=material_names,
    )
    return rollout_metrics(pair, metrics)


def _as_rollout(prediction: Prediction, case: Trajectory, history: int, metadata: DatasetMetadata) -> Rollout:
    return Rollout(
        truth=case,
        predicted=_host_float64(prediction.position).numpy().astype(np.float32),
        history=history,
        metadata=metadata,
        source=case.key,
    )


def _mean_over_cases(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def _entry(
    candidate: Candidate,
    summaries: list[dict[str, float | None]],
    timings: list[Timing],
    curves: list,
    keys: list[str],
    rollout_files: list[Path | None],
) -> Entry:
    # The mean of the cases' times is the entry's seconds; metrics are the errors (and counts) averaged.
    names = list(dict.fromkeys(name for summary in summaries for name in summary if name != "seconds_per_rollout"))
    metrics = {name: _mean_over_cases([s.get(name) for s in summaries]) for name in names}
    same_length = curves and all(c is not None and c.shape == curves[0].shape for c in curves)
    return Entry(
        name=candidate.name,
        kind=candidate.kind,
        settings=candidate.settings,
        device=candidate.device or "cpu",
        reference=candidate.reference,
        seconds=float(np.mean([t.median for t in timings])),
        spread=float(np.mean([t.spread for t in timings])),
        metrics=metrics,
        mse_per_step=np.mean(curves, axis=0) if same_length else None,
        cases=dict(zip(keys, summaries, strict=True)),
        rollout_files=tuple(rollout_files),
    )


def _with_speedup(entry: Entry, reference_seconds: float) -> Entry:
    return Entry(**{**entry.__dict__, "speedup": reference_seconds / entry.seconds if entry.seconds > 0 else math.inf})
