"""The report as text: the Markdown table with its notes, and the CSV files of entries and of cases."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from .records import WALL_HELD, WARNING_ERROR, WARNING_FLAG, WARNING_SCORE, Report
from .timing import format_hardware

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
    lines += _deposit_warnings(report)
    lines += ["", "Metrics (L: the dataset's length unit, s: seconds):", ""]
    lines += [f"- `{name}`: {meaning}" for name, meaning in report.metric_units.items()]
    lines.append("")
    return "\n".join(lines)


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


def _deposit_warnings(report: Report) -> list[str]:
    """Per learned model that carries a deposit warning, the cases it flags (the ones to check with a simulator)."""
    lines = []
    for e in report.entries:
        scored = {key: c for key, c in e.cases.items() if c.get(WARNING_FLAG) is not None}
        if scored:
            flagged = [key for key, c in scored.items() if c[WARNING_FLAG]]
            named = f": {', '.join(flagged)}" if flagged else ""
            error = next(iter(scored.values())).get(WARNING_ERROR)  # one warning per model
            told = f" as more than {error:g} % off" if error is not None else ""
            lines.append(f"- {e.name}: {len(flagged)} of {len(scored)} case(s) flagged{told}{named}")
    if not lines:
        return []
    intro = (
        "Deposit warning (the model's own, fitted on its training scenes): cases whose extent or height may be "
        f"further off than it was fitted to tell; `{WARNING_SCORE}` in cases.csv has every score:"
    )
    return ["", intro, "", *lines]


SPREAD_METRICS = ("runout_error_pct", "sinkhorn_final_pct")
"""Metrics whose median and worst case over the test cases the Markdown report states (cases.csv has all)."""
FREE_DEPOSIT = "free_deposit"
"""Per case: 1 where the true deposit stops short of a side wall; their extent errors are stated apart."""


def _spread_over_cases(report: Report) -> list[str]:
    """Median and worst case of the headline errors over the cases, when there are several."""
    if report.num_cases < 2:
        return []
    lines = ["", f"Spread over the {report.num_cases} cases (median / worst):", ""]
    for e in report.entries:
        parts = []
        for metric in SPREAD_METRICS:
            spread = _median_worst([c.get(metric) for c in e.cases.values()])
            if spread:
                parts.append(f"{metric} {spread}")
        # Where the true deposit spans the box its extent is the box's: the extent errors that are the model's.
        free = [c.get("extent_error_pct") for c in e.cases.values() if c.get(FREE_DEPOSIT) == 1.0]
        spread = _median_worst(free)
        if spread:
            parts.append(f"extent_error_pct of the {len(free)} free deposit(s) {spread}")
        if parts:
            lines.append(f"- {e.name}: " + "; ".join(parts))
    return lines if len(lines) > 3 else []


def _median_worst(values: list[float | None]) -> str | None:
    """``median / worst`` of ``values``; None when there are none or any is missing."""
    present = [v for v in values if v is not None]
    if not values or len(present) < len(values):
        return None
    return f"{_format(float(np.median(present)))} / {_format(max(present))}"


def write_cases_csv(report: Report, path: Path) -> None:
    """One row per entry and case with every metric of that case; missing values are empty cells."""
    metric_names = list(dict.fromkeys(name for e in report.entries for c in e.cases.values() for name in c))
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["name", "case", *metric_names])
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
