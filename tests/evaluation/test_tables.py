"""The report as text: the Markdown table and its notes, and the CSV files of entries and cases."""

from __future__ import annotations

import csv

from report_records import report

from gns_framework.evaluation.tables import markdown_table, write_cases_csv, write_csv


def test_the_markdown_table_names_the_reference_and_states_the_spread():
    text = markdown_table(report())
    assert "| mpm (reference) | simulator | grid 96 |" in text
    assert "speed-up vs mpm" in text and "| 4 |" in text
    assert "Spread over the 2 cases (median / worst):" in text
    assert "- model: runout_error_pct 7.5 / 10; sinkhorn_final_pct 1.5 / 2" in text
    assert "Particles a wall held" not in text, "nothing is said when no wall held anything"
    assert "- `mse_20`: L^2, position MSE at step 20" in text


def test_walls_held_are_stated_per_model():
    text = markdown_table(report(held=(3, 0)))
    assert "- model: 3 particle(s) in 1 of 2 case(s), at most 3 in one" in text


def test_csv_files_hold_every_metric_of_every_entry_and_case(tmp_path):
    made = report()
    write_csv(made, tmp_path / "report.csv")
    write_cases_csv(made, tmp_path / "cases.csv")
    rows = list(csv.DictReader((tmp_path / "report.csv").open()))
    assert [row["name"] for row in rows] == ["mpm", "model"]
    assert rows[1]["speedup"] == "4.0" and rows[1]["mse_1"] == "" and rows[0]["runout_error_pct"] == "7.5"
    cases = list(csv.DictReader((tmp_path / "cases.csv").open()))
    assert [(row["name"], row["case"]) for row in cases] == [
        ("mpm", "case0"),
        ("mpm", "case1"),
        ("model", "case0"),
        ("model", "case1"),
    ]
    assert cases[3]["runout_error_pct"] == "10.0"


def test_the_extent_errors_of_free_deposits_are_stated_apart():
    made = report()
    model = made.entries[1]
    model.cases["case0"].update(extent_error_pct=0.0, free_deposit=0.0)  # wall to wall: the box's extent
    model.cases["case1"].update(extent_error_pct=12.0, free_deposit=1.0)
    assert "extent_error_pct of the 1 free deposit(s) 12 / 12" in markdown_table(made)
    model.cases["case1"]["free_deposit"] = 0.0
    assert "free deposit" not in markdown_table(made), "nothing is said when no deposit is free"
