"""The deterministic-sums switch: on by default, set from the recipe, a plain bool."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gns_framework.runtime.deterministic import deterministic_sums, set_deterministic_sums


@pytest.fixture(autouse=True)
def switch_restored():
    """The switch is process-wide: leave it as the other tests found it."""
    before = deterministic_sums()
    yield
    set_deterministic_sums(before)


def test_sums_are_deterministic_in_a_fresh_process():
    # A fresh interpreter, since tests earlier in the session may have flipped the switch.
    code = "from gns_framework.runtime.deterministic import deterministic_sums; print(deterministic_sums())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"


def test_the_switch_holds_what_was_set_as_a_bool():
    set_deterministic_sums(False)
    assert deterministic_sums() is False
    set_deterministic_sums(1)
    assert deterministic_sums() is True
    set_deterministic_sums(0)
    assert deterministic_sums() is False
