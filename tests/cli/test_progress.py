"""The report phase's bar: quiet gives no callback, otherwise the bar counts cases and names the candidate."""

from __future__ import annotations

from gns_framework.cli.progress import report_progress


def test_quiet_gives_no_callback():
    with report_progress(quiet=True) as progress:
        assert progress is None


def test_the_bar_counts_cases_and_names_the_candidate(capsys):
    with report_progress(quiet=False) as progress:
        progress("gns", 1, 3)
        progress("mls_mpm grid 24", 3, 3)
    err = capsys.readouterr().err
    assert "timing and scoring" in err and "3/3" in err and "mls_mpm grid 24" in err
