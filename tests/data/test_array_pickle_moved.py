"""gns_framework.data.array_pickle moved: its names still import from there, with a warning naming the new home."""

from __future__ import annotations

import pytest

import gns_framework.data.array_pickle as old_home
from gns_builtins.datasets._formats import array_pickle
from gns_framework.data import pickle_grant


@pytest.mark.parametrize(
    "name, module",
    [("read_npy_object_array", array_pickle), ("RefusedGlobal", array_pickle), ("pickle_granted", pickle_grant)],
)
def test_a_moved_name_warns_and_is_the_same_object(name, module):
    with pytest.warns(DeprecationWarning, match=f"{name} moved to {module.__name__}.{name}"):
        assert getattr(old_home, name) is getattr(module, name)


def test_an_unknown_name_is_still_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        old_home.nothing_here  # noqa: B018
