"""Writing a report's files into a folder: Markdown, CSVs and plots."""

from __future__ import annotations

from pathlib import Path

from .plots import plot_error_over_rollout, plot_error_vs_time
from .records import Report
from .tables import markdown_table, write_cases_csv, write_csv


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
