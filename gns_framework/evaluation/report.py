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

import csv
import math
import time
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..data.metadata import DatasetMetadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..io.rollout_file import save_rollout
from ..safe_names import ensure_inside, unique_components
from ..plugin_types import Metric
from ..runtime.device import is_cuda
from .metrics import DEFAULT_HORIZONS, ParticleRollout, RolloutPair, metric_units, rollout_metrics, summarise
from .timing import Timing, format_hardware, hardware_description, time_call

Kind = Literal["learned", "simulator"]


@dataclass(frozen=True)
class Prediction:
    """A candidate's rollout of a case.

    A learned model predicts the case's own particles; a simulator at another
    resolution has its own particles, so it brings their types and start frame.

    Attributes:
        position: (S, N', d) positions of the S frames after the case's C input frames, L
            (a NumPy array or a tensor on any device).
        particle_type: (N',) int64, or None for the case's particles.
        start: (N', d) the frame before the first one, L, or None for the case's last input frame.
        held: see below.
    """

    position: np.ndarray | torch.Tensor
    particle_type: np.ndarray | None = None
    start: np.ndarray | torch.Tensor | None = None
    held: int | None = None
    """Particles a wall held: they left the domain and the rollout guard put them back (None: not guarded)."""


@dataclass(frozen=True)
class Candidate:
    """A way of producing rollouts whose error and run time are reported.

    Attributes:
        name: row label in the report.
        kind: ``learned`` or ``simulator``.
        simulate: case (a test trajectory) -> its rollout; called once per warm-up and repeat, and timed.
        reference: the simulator setting that produced the ground truth (at most one).
        settings: resolution, time step or checkpoint, for the table.
        device: where ``simulate`` computes (synchronised around each timing).
        simulate_batch: cases -> their rollouts in order, computed together; when given,
            the cases are rolled out ``batch`` at a time and each is charged its share of
            the batch's time (the throughput a parametric study gets).
        batch: cases per ``simulate_batch`` call.
    """

    name: str
    kind: Kind
    simulate: Callable[[Trajectory], Prediction]
    reference: bool = False
    settings: str = ""
    device: str | None = None
    simulate_batch: Callable[[Sequence[Trajectory]], list[Prediction]] | None = None
    batch: int = 1


@dataclass(frozen=True)
class Entry:
    """One row of the report: a candidate's mean error over the cases and its run time.

    Attributes:
        seconds: mean over cases of the median wall-clock time of one rollout, s.
        spread: mean over cases of (slowest - fastest) repeat, s.
        metrics: metric name -> mean over cases (None when missing), see ``Report.metric_units``.
        mse_per_step: (S,) position MSE per rolled-out frame averaged over cases, or None.
        speedup: reference seconds / these seconds, or None without a reference.
        cases: case key -> that case's metrics (the spread a mean hides: the worst collapse matters).
        rollout_files: per case, in order, the rollout file written for it (``rollout_dir``), or None.
    """

    name: str
    kind: Kind
    settings: str
    device: str
    reference: bool
    seconds: float
    spread: float
    metrics: dict[str, float | None]
    mse_per_step: np.ndarray | None
    speedup: float | None = None
    cases: dict[str, dict[str, float | None]] = field(default_factory=dict)
    rollout_files: tuple[Path | None, ...] = ()


@dataclass(frozen=True)
class Report:
    entries: list[Entry]
    error_metric: str
    num_cases: int
    repeats: int
    warmup: int
    dt: float
    hardware: dict[str, str | int] = field(default_factory=dict)
    metric_units: dict[str, str] = field(default_factory=dict)
    """Name (or family pattern) -> unit and meaning of every metric reported."""
    warnings: tuple[str, ...] = ()
    """What the reader must know before trusting the figures (data outside a model's training envelope)."""

    @property
    def reference(self) -> Entry | None:
        return next((e for e in self.entries if e.reference), None)


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
    folders = dict(zip(names, unique_components(names)))
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
        for case, file_name in zip(cases, files):
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
            (case, file, prediction, share) for case, file, prediction in zip(chunk, files[start:], predictions)
        )


def score_rollout(
    rollout: Rollout,
    *,
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    granular_types: Collection[int] = (),
    material_names: Mapping[int, str] | None = None,
    kinematic_types: Collection[int] | None = None,
    metrics: Sequence[Metric] | None = None,
) -> dict[str, float | None]:
    """Every metric of a rollout's prediction against its ground truth (no timing); it needs its metadata."""
    if rollout.metadata is None:
        raise ValueError(f"{rollout.source}: scoring a rollout needs the dataset's metadata; the rollout has none")
    scores = score_prediction(
        Prediction(rollout.predicted),
        rollout.truth,
        rollout.history,
        rollout.metadata,
        horizons,
        granular_types,
        material_names,
        kinematic_types=kinematic_types,
        metrics=metrics,
    )
    return summarise(scores)


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
    gives the frames' time step and the domain's bounds.
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
        bounds=metadata.bounds,
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
        cases=dict(zip(keys, summaries)),
        rollout_files=tuple(rollout_files),
    )


def _with_speedup(entry: Entry, reference_seconds: float) -> Entry:
    return Entry(**{**entry.__dict__, "speedup": reference_seconds / entry.seconds if entry.seconds > 0 else math.inf})


HEADLINE_METRICS = ("mse_1", "mse_20", "mse_full", "sinkhorn_final", "kinetic_energy_error_pct", "runout_error_pct")
"""Columns of the Markdown table besides time, speed-up and error (the CSV has all)."""


def _format(value: float | None, digits: int = 3) -> str:
    if value is None:
        return "-"
    if math.isinf(value):
        return "inf"
    return f"{value:.{digits}g}"


def markdown_table(report: Report) -> str:
    """The report as Markdown: header with hardware and protocol, table, metric legend."""
    reference = report.reference
    speedup_header = f"speed-up vs {reference.name}" if reference else "speed-up"
    headline = [m for m in HEADLINE_METRICS if any(e.metrics.get(m) is not None for e in report.entries)]
    if any(e.metrics.get("diverged") for e in report.entries):
        headline.append("diverged")
    columns = [
        "model",
        "kind",
        "settings",
        "time per rollout (s)",
        speedup_header,
        f"error (%) [{report.error_metric}]",
    ]
    lines = [
        "# Error against run time",
        "",
        f"Hardware: {format_hardware(report.hardware)}.",
        (
            f"Timing: median of {report.repeats} repeats per rollout after {report.warmup} warm-up run(s), "
            f"device synchronised; mean over {report.num_cases} test case(s)."
        ),
        *(
            ["", "**Warning: data outside a model's training envelope (the model extrapolates here):**", ""]
            + [f"- {line}" for line in report.warnings]
            if report.warnings
            else []
        ),
        "",
        "| " + " | ".join(columns + headline) + " |",
        "|" + "|".join(["---"] * 3 + ["---:"] * (len(columns) - 3 + len(headline))) + "|",
    ]
    for e in report.entries:
        name = f"{e.name} (reference)" if e.reference else e.name
        row = [
            name,
            e.kind,
            e.settings or "-",
            _format(e.seconds),
            _format(e.speedup),
            _format(e.metrics.get(report.error_metric)),
        ]
        row += [_format(e.metrics.get(m)) for m in headline]
        lines.append("| " + " | ".join(row) + " |")
    lines += _spread_over_cases(report)
    lines += _walls_held(report)
    lines += ["", "Metrics (L: the dataset's length unit, s: seconds):", ""]
    lines += [f"- `{name}`: {meaning}" for name, meaning in report.metric_units.items()]
    lines.append("")
    return "\n".join(lines)


WALL_HELD = "wall_held_particles"
"""Per case: the particles that left the domain in a learned rollout and were put back by the model's guard."""


def _walls_held(report: Report) -> list[str]:
    """Per learned model, the particles a wall held and in how many cases (none of this when nothing escaped)."""
    lines = []
    for e in report.entries:
        held = [float(value) for c in e.cases.values() if (value := c.get(WALL_HELD)) is not None]
        if held and any(held):
            cases = sum(1 for h in held if h)
            lines.append(
                f"- {e.name}: {int(sum(held))} particle(s) in {cases} of {len(held)} case(s), at most {int(max(held))} "
                "in one"
            )
    if not lines:
        return []
    intro = (
        "Particles a wall held (they left the box; the model's `rollout.guard` put them back, as `gns rollout` does):"
    )
    return ["", intro, "", *lines]


SPREAD_METRICS = ("runout_error_pct", "sinkhorn_final_pct")
"""Metrics whose median and worst case over the test cases the Markdown report states (cases.csv has all)."""


def _spread_over_cases(report: Report) -> list[str]:
    """Median and worst case of the headline errors over the cases, when there are several."""
    if report.num_cases < 2:
        return []
    lines = ["", f"Spread over the {report.num_cases} cases (median / worst):", ""]
    for e in report.entries:
        parts = []
        for metric in SPREAD_METRICS:
            values = [c.get(metric) for c in e.cases.values()]
            present = [v for v in values if v is not None]
            if values and len(present) == len(values):
                parts.append(f"{metric} {_format(float(np.median(present)))} / {_format(max(present))}")
        if parts:
            lines.append(f"- {e.name}: " + "; ".join(parts))
    return lines if len(lines) > 3 else []


def write_cases_csv(report: Report, path: Path) -> None:
    """One row per entry and case with every metric of that case; missing values are empty cells."""
    metric_names = list(dict.fromkeys(name for e in report.entries for c in e.cases.values() for name in c))
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["name", "case"] + metric_names)
        for e in report.entries:
            for key, metrics in e.cases.items():
                row = [metrics.get(name) for name in metric_names]
                writer.writerow([e.name, key] + ["" if v is None else v for v in row])


def write_csv(report: Report, path: Path) -> None:
    """One row per entry with every metric; missing values are empty cells."""
    metric_names = list(dict.fromkeys(name for e in report.entries for name in e.metrics))
    columns = ["name", "kind", "settings", "device", "reference", "seconds_per_rollout", "seconds_spread", "speedup"]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns + metric_names)
        for e in report.entries:
            row = [e.name, e.kind, e.settings, e.device, e.reference, e.seconds, e.spread, e.speedup]
            row += [e.metrics.get(name) for name in metric_names]
            writer.writerow(["" if v is None else v for v in row])


def case_range(entry: Entry, metric: str) -> tuple[float, float] | None:
    """(best, worst) of ``metric`` over the entry's cases with a finite value, or None when none has one."""
    values = [v for v in (case.get(metric) for case in entry.cases.values()) if v is not None and math.isfinite(v)]
    return (min(values), max(values)) if values else None


def _log_axis_ticks(axis, low: float, high: float) -> None:
    """Plain-number labels on a log axis, only as many as fit: 1-2-5 steps over up to three decades, else decades."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = math.log10(high / low) if low > 0 and high > low else 0.0
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0) if decades <= 3 else (1.0,)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_formatter(NullFormatter())


def plot_error_vs_time(report: Report, path: Path) -> None:
    """Log-log scatter of the error metric against run time per rollout, with the spread behind each point.

    Vertical bars run from the best to the worst case (the mean hides the worst
    collapse); horizontal bars span the mean spread of the timed repeats (slowest
    minus fastest). The reference simulator has no error against itself: it is drawn
    as a vertical line at its run time. Entries with no finite positive error are
    listed in the title instead of silently dropped.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.6, 4.8))
    left_out, drawn_x, drawn_y = [], [], []
    # Points are numbered and named in a key beside the axes: names written at the points
    # overlap as soon as a few models (precisions, batch rows) sit at similar times.
    key: list[str] = []
    for kind, marker in (("simulator", "s"), ("learned", "o")):
        points = []
        for e in report.entries:
            if e.kind != kind or e.reference:
                continue
            error = e.metrics.get(report.error_metric)
            if error is None or not math.isfinite(error) or error <= 0:
                left_out.append(e.name)
                continue
            low, high = case_range(e, report.error_metric) or (error, error)
            points.append((e.seconds, error, e.name, min(low, error), max(high, error), e.spread))
        if not points:
            continue
        xs, ys, names, lows, highs, spreads = zip(*points)
        # Markers and bars only: settings may vary along different axes (resolution, time
        # step), so a line through them would suggest a trade-off curve that was not measured.
        ax.errorbar(
            xs,
            ys,
            yerr=[[y - lo for y, lo in zip(ys, lows)], [hi - y for y, hi in zip(ys, highs)]],
            xerr=[[min(s / 2, 0.9 * x) for x, s in zip(xs, spreads)], [s / 2 for s in spreads]],
            marker=marker,
            linestyle="none",
            capsize=2,
            elinewidth=0.8,
            label="ground-truth simulator" if kind == "simulator" else "learned simulator",
        )
        for x, y, name in zip(xs, ys, names):
            key.append(f"{len(key) + 1}  {name}")
            ax.annotate(str(len(key)), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
        drawn_x += [x for x in xs] + [x + s / 2 for x, s in zip(xs, spreads)]
        drawn_y += [v for v in (*lows, *highs) if v > 0]
    if report.reference is not None:
        ax.axvline(report.reference.seconds, color="k", linestyle="--", label=f"{report.reference.name} (reference)")
        drawn_x.append(report.reference.seconds)
    ax.set_xscale("log")
    ax.set_yscale("log")
    if drawn_x and drawn_y:
        _log_axis_ticks(ax.xaxis, min(drawn_x), max(drawn_x))
        _log_axis_ticks(ax.yaxis, min(drawn_y), max(drawn_y))
    ax.set_xlabel("wall-clock time per rollout (s); bars: spread of the timed repeats")
    ax.set_ylabel(f"{report.error_metric} (%), mean; bars: best to worst case")
    title = f"Error against run time ({report.num_cases} cases)"
    if left_out:
        title += f"\n(no finite error: {', '.join(left_out)})"
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout(rect=(0.0, 0.0, 0.6, 1.0))
    fig.text(0.61, 0.5, "\n".join(key), va="center", ha="left", fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_error_over_rollout(report: Report, path: Path) -> None:
    """Position MSE per frame against simulated time, one line per entry that has it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for e in report.entries:
        if e.mse_per_step is None or e.reference:
            continue
        time_s = report.dt * np.arange(1, len(e.mse_per_step) + 1)
        finite = np.isfinite(e.mse_per_step) & (e.mse_per_step > 0)
        ax.plot(time_s[finite], e.mse_per_step[finite], label=e.name)
    ax.set_yscale("log")
    ax.set_xlabel("simulated time since the last input frame (s)")
    ax.set_ylabel("position MSE (L^2)")
    ax.set_title("Error over rollout time", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(report: Report, out_dir: str | Path) -> dict[str, Path]:
    """Write ``report.md``, ``report.csv``, ``cases.csv``, ``error_vs_time.png`` and ``error_over_rollout.png``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "markdown": out_dir / "report.md",
        "csv": out_dir / "report.csv",
        "cases_csv": out_dir / "cases.csv",
        "error_vs_time": out_dir / "error_vs_time.png",
        "error_over_rollout": out_dir / "error_over_rollout.png",
    }
    paths["markdown"].write_text(markdown_table(report))
    write_csv(report, paths["csv"])
    write_cases_csv(report, paths["cases_csv"])
    plot_error_vs_time(report, paths["error_vs_time"])
    plot_error_over_rollout(report, paths["error_over_rollout"])
    return paths
