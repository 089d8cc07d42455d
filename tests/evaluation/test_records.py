"""The report's records: the reference entry is found by its flag."""

from __future__ import annotations

from dataclasses import replace

from report_records import report


def test_the_reference_is_the_entry_flagged_so():
    made = report()
    assert made.reference is not None and made.reference.name == "mpm"
    assert replace(made, entries=made.entries[1:]).reference is None
