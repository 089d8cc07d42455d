"""The contracts package: every contract importable from gns_framework.contracts; the old name of ModelSetup warns."""

from __future__ import annotations

import warnings

import pytest

import gns_framework.contracts as contracts


def test_every_exported_name_imports_from_the_package():
    for name in contracts.__all__:
        assert getattr(contracts, name) is not None, name
    exported = [getattr(contracts, n) for n in contracts.__all__]
    assert all(any(kind is e for e in exported) for kind in contracts.COMPONENT_KINDS.values())


def test_the_old_name_of_the_model_setup_still_imports_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="Scene is now ModelSetup"):
        from gns_framework.contracts import Scene
    assert Scene is contracts.ModelSetup


def test_the_new_name_imports_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from gns_framework.contracts import ModelSetup
    assert ModelSetup.__name__ == "ModelSetup"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Sceen'"):
        contracts.Sceen  # noqa: B018
