"""Old homes of moved names: the name still imports, is the same object, and the warning names its new home."""

from __future__ import annotations

import importlib

import pytest

from gns_framework.moved import formerly_positional, renamed, renamed_attribute, renamed_keywords
from gns_framework.plugins import load_registry
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


class Holder:
    old = renamed_attribute("old", "new")

    @renamed_keywords(old="new")
    def __init__(self, new, other=0):
        self.new, self.other = new, other


def test_a_renamed_attribute_warns_names_the_class_and_reads_the_new_one():
    class Sub(Holder):
        pass

    with pytest.warns(DeprecationWarning, match=r"^Sub\.old is now \.new; the old name goes in 0\.3$"):
        assert Sub(1).old == 1
    with pytest.raises(AttributeError):
        Sub(1).old = 2


def test_a_renamed_keyword_reaches_the_new_one_with_a_warning():
    with pytest.warns(DeprecationWarning, match=r"^Holder\(old=...\) is now Holder\(new=...\); the old keyword"):
        held = Holder(old=3, other=4)
    assert (held.new, held.other) == (3, 4)
    with pytest.warns(DeprecationWarning), pytest.raises(TypeError, match="both old= and its new name new="):
        Holder(old=3, new=4)


def test_a_function_that_still_has_the_old_parameter_is_left_as_it_is():
    def function(old):
        return old

    assert renamed_keywords(old="new")(function) is function


def test_a_class_renamed_at_once_takes_and_reads_the_old_name_with_warnings():
    @renamed("old", "new")
    class Renamed:
        def __init__(self, new):
            self.new = new

    with pytest.warns(DeprecationWarning, match=r"Renamed\(old=...\) is now .*Renamed\(new=...\)"):
        held = Renamed(old=5)
    with pytest.warns(DeprecationWarning, match=r"^Renamed\.old is now \.new"):
        assert held.old == 5
    assert Renamed(new=6).new == 6


class _Old:
    @formerly_positional("first", "second", after=2)
    def __init__(self, a: int, *, first: int = 1, second: int = 2):
        self.values = (a, first, second)


def test_formerly_positional_arguments_still_reach_their_keywords_with_a_warning():
    assert _Old(0, first=5).values == (0, 5, 2)
    with pytest.warns(DeprecationWarning, match=r"_Old\(\): pass first, second by keyword"):
        assert _Old(0, 7, 8).values == (0, 7, 8)
    with pytest.warns(DeprecationWarning), pytest.raises(TypeError, match="first by position and by keyword"):
        _Old(0, 7, first=7)
    with pytest.raises(TypeError, match="at most 4 positional arguments, got 5"):
        _Old(0, 7, 8, 9)


def test_the_trainer_still_takes_its_run_folder_by_position(tmp_path, dataset_2d):
    from gns_framework.training.trainer import Trainer
    from tests.tiny import tiny_recipe

    registry = load_registry()
    with pytest.warns(DeprecationWarning, match="pass run_dir by keyword"):
        trainer = Trainer(tiny_recipe(dataset_2d, registry), registry, tmp_path / "run")
    assert trainer.run_dir == tmp_path / "run"
