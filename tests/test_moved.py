"""Old homes of moved names: the name still imports, is the same object, and the warning names its new home."""

from __future__ import annotations

import importlib

import pytest

from gns_framework.runtime import processes, teams

MOVED = [
    ("gns_framework.training.processes", "Processes", processes),
    ("gns_framework.training.teams", "team_of", teams),
]


@pytest.mark.parametrize("old, name, home", MOVED)
def test_a_moved_name_warns_and_is_the_same_object(old, name, home):
    with pytest.warns(DeprecationWarning, match=rf"{old}.{name} moved to {home.__name__}.{name}; import it from"):
        assert getattr(importlib.import_module(old), name) is getattr(home, name)


def test_from_import_of_a_moved_name_works():
    with pytest.warns(DeprecationWarning, match="Processes moved to gns_framework.runtime.processes"):
        from gns_framework.training.processes import Processes
    assert Processes is processes.Processes


def test_an_unknown_name_is_still_an_attribute_error():
    old = importlib.import_module("gns_framework.training.processes")
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        old.nothing_here  # noqa: B018
