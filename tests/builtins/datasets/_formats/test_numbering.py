"""Trajectory numbers: a split named by distinct decimal numbers keeps them, any other split is numbered in order."""

from __future__ import annotations

import numpy as np
import pytest

from gns_builtins.datasets._formats.numbering import trajectory_numbers
from gns_framework.data.trajectory import Trajectory


def named(*keys: str) -> list[Trajectory]:
    return [Trajectory(np.zeros((2, 1, 2), np.float32), np.zeros(1, np.int64), key=key) for key in keys]


def test_numbered_trajectories_keep_their_numbers():
    # Test trajectory 1 of a DeepMind file stays 1 when converted, though it comes first.
    assert trajectory_numbers(named("1")) == [1]
    assert trajectory_numbers(named("7", "00003", "12")) == [7, 3, 12]


@pytest.mark.parametrize(
    "keys, why",
    [
        (("1", "a"), "one name is not a number"),
        (("1", "01"), "two names are the same number"),
        (("2", "-1"), "a sign is not a decimal digit"),
        (("2", "\u0663"), "a non-ASCII digit (Arabic-Indic three) is not a stored number"),
        (("", "1"), "an empty name"),
    ],
)
def test_any_other_split_is_numbered_in_its_order(keys, why):
    assert trajectory_numbers(named(*keys)) == [0, 1], why


def test_an_empty_split_has_no_numbers():
    assert trajectory_numbers([]) == []
