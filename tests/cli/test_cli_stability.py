"""``gns stability`` (``gns_framework.cli.stability``): a header, one line per case as it is computed, a summary,
each failing case again at the end, and exit status 1 when any case fails. The report here is a stand-in of a few
rows; the real report, and that it passes on the built-ins, are in tests/stability/test_stability_report.py."""

from __future__ import annotations

import pytest

from gns_framework.cli import main
from gns_framework.cli import stability as stability_command
from gns_framework.stability.report import Row, format_row

ROWS = [
    Row("spring chain", "semi_implicit_euler", "limit as theory", "dt 2.0e-03"),
    Row("spring chain", "velocity_verlet", "diverged", "energy x 1e9", failing=True),
    Row("near-collision", "explicit_euler", "energy grows", "+12 %"),
    Row("rollout guard", "stop", "not stopped", "", failing=True),
]


@pytest.fixture
def report(monkeypatch):
    """The stand-in report, and the thread counts the command set."""
    threads = []
    monkeypatch.setattr(stability_command, "load_registry", lambda: "registry")
    monkeypatch.setattr(stability_command, "run_report", lambda registry: iter(ROWS) if registry == "registry" else [])
    monkeypatch.setattr(stability_command.torch, "set_num_threads", threads.append)
    return threads


def test_every_row_is_printed_and_the_failing_ones_again_with_exit_status_1(report, capsys):
    assert main(["stability", "--threads", "3"]) == 1
    assert report == [3]
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == format_row(Row("group", "case", "outcome", "figures"))
    assert lines[1:5] == [format_row(row) for row in ROWS]
    assert lines[5] == ""
    assert lines[6].startswith("2 failing case(s); ") and lines[6].endswith(" s")
    assert lines[7:] == [
        "FAIL: spring chain: velocity_verlet: diverged",
        "FAIL: rollout guard: stop: not stopped",
    ]


def test_a_report_without_failures_exits_0_on_one_thread_by_default(report, monkeypatch, capsys):
    monkeypatch.setattr(stability_command, "run_report", lambda registry: iter(r for r in ROWS if not r.failing))
    assert main(["stability"]) == 0
    assert report == [1]
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].startswith("0 failing case(s); ") and not any(line.startswith("FAIL") for line in lines)


def test_threads_must_be_a_positive_count(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["stability", "--threads", "0"])
    assert exited.value.code == 2 and "argument --threads: must be >= 1, got 0" in capsys.readouterr().err
