"""The report's plots: each entry's range over cases, and the two PNG figures."""

from __future__ import annotations

import math

from report_records import entry, report

from gns_framework.evaluation.plots import case_range, plot_error_over_rollout, plot_error_vs_time


def test_the_case_range_skips_missing_and_infinite_values():
    made = entry("model")
    assert case_range(made, "runout_error_pct") == (5.0, 10.0)
    made.cases["case0"]["runout_error_pct"] = math.inf
    made.cases["case1"]["runout_error_pct"] = None
    assert case_range(made, "runout_error_pct") is None
    assert case_range(made, "absent") is None


def test_both_plots_are_written_as_png(tmp_path):
    for plot, name in ((plot_error_vs_time, "vs_time.png"), (plot_error_over_rollout, "over_rollout.png")):
        plot(report(), tmp_path / name)
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
