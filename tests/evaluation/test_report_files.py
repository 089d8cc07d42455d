"""write_report: the five files of a report in one folder (their content: test_tables.py, test_plots.py)."""

from __future__ import annotations

from report_records import report

from gns_framework.evaluation.report_files import write_report


def test_the_five_files_are_written_where_asked(tmp_path):
    paths = write_report(report(), tmp_path / "new" / "folder")
    assert {path.name for path in paths.values()} == {
        "report.md",
        "report.csv",
        "cases.csv",
        "error_vs_time.png",
        "error_over_rollout.png",
    }
    assert all(path.parent == tmp_path / "new" / "folder" and path.stat().st_size > 0 for path in paths.values())
