"""benchmarks/reference_spread.py: a scene's spread is the largest difference of the simulator's other runs from the
data, and the summary counts scenes by it and by the learned error."""

from __future__ import annotations

from load_script import load_script

reference_spread = load_script("benchmarks/reference_spread.py")


def _row(scene: str, learned: tuple[float, float], *runs: tuple[float, float]) -> dict:
    return {
        "group": "held-out",
        "scene": scene,
        "learned": {"extent": learned[0], "height": learned[1]},
        "mpm": {str(i + 1): {"extent": e, "height": h} for i, (e, h) in enumerate(runs)},
    }


def test_the_spread_is_the_largest_difference_of_any_other_run(capsys):
    rows = [
        _row("settled", (1.0, 2.0), (0.5, 0.2), (0.1, 1.5)),
        _row("missed but settled", (31.0, 3.0), (1.7, 0.9), (4.5, 0.8)),
        _row("undecided", (18.0, 1.0), (12.0, 0.5), (27.0, 0.6)),
    ]
    assert reference_spread.spread(rows[0]) == 1.5 and reference_spread.spread(rows[2]) == 27.0
    summary = reference_spread.report(rows)
    assert summary["spread_worst_pct"] == 27.0 and summary["spread_median_pct"] == 4.5
    assert (summary["spread_over_bad"], summary["spread_over_10"], summary["learned_over_bad"]) == (1, 1, 2)
    # Only "missed but settled" is further from the data than its spread plus 15 %: 31 > 4.5 + 15; 18 < 27 + 15.
    assert summary["bad_with_spread_over_10"] == 1 and summary["learned_beyond_spread_plus_bad"] == 1
    table = capsys.readouterr().out
    assert table.index("missed but settled") < table.index("undecided") < table.index("| settled")
