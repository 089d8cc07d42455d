"""The report's plots: error against run time (log-log, with each entry's spread over cases) and error over rollout
time.

matplotlib is imported only when a plot is drawn.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .records import Entry, Report


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
        xs, ys, names, lows, highs, spreads = zip(*points, strict=True)
        # Markers and bars only: settings may vary along different axes (resolution, time
        # step), so a line through them would suggest a trade-off curve that was not measured.
        ax.errorbar(
            xs,
            ys,
            yerr=[[y - lo for y, lo in zip(ys, lows, strict=True)], [hi - y for y, hi in zip(ys, highs, strict=True)]],
            xerr=[[min(s / 2, 0.9 * x) for x, s in zip(xs, spreads, strict=True)], [s / 2 for s in spreads]],
            marker=marker,
            linestyle="none",
            capsize=2,
            elinewidth=0.8,
            label="ground-truth simulator" if kind == "simulator" else "learned simulator",
        )
        for x, y, name in zip(xs, ys, names, strict=True):
            key.append(f"{len(key) + 1}  {name}")
            ax.annotate(str(len(key)), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
        drawn_x += [x for x in xs] + [x + s / 2 for x, s in zip(xs, spreads, strict=True)]
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
