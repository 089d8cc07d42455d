"""The hook specifications: one hook per component kind (named gns_<kind>s), plus metrics and commands."""

from __future__ import annotations

import pluggy
import pytest

from gns_framework import hookspecs
from gns_framework.contracts import COMPONENT_KINDS
from gns_framework.hookspecs import PROJECT, hookimpl


def test_every_kind_has_a_hook():
    for kind in COMPONENT_KINDS:
        assert hasattr(hookspecs, hookspecs.hook_of_kind(kind))


@pytest.mark.parametrize(
    "kind, hook",
    [("graph_builder", "gns_graph_builders"), ("dataset", "gns_datasets"), ("simulator", "gns_simulators")],
)
def test_the_hook_of_a_kind_is_gns_kind_plural(kind, hook):
    assert hookspecs.hook_of_kind(kind) == hook


def _manager() -> pluggy.PluginManager:
    manager = pluggy.PluginManager(PROJECT)
    manager.add_hookspecs(hookspecs)
    return manager


def test_the_declared_hooks_are_the_kinds_the_metrics_and_the_commands():
    declared = {name for name in dir(_manager().hook) if name.startswith("gns_")}
    assert declared == {hookspecs.hook_of_kind(k) for k in COMPONENT_KINDS} | {"gns_metrics", "gns_commands"}


def test_a_plugin_marked_with_hookimpl_is_called_through_its_hook():
    class Extra:
        @staticmethod
        @hookimpl
        def gns_metrics():
            return ["a metric record"]

    manager = _manager()
    manager.register(Extra, name="extra")
    assert manager.hook.gns_metrics() == [["a metric record"]]  # one list per implementing plugin


def test_a_misspelt_hook_is_refused_when_plugins_are_checked():
    # A plugin implementing `gns_processor` (no s) would otherwise be ignored without a word.
    class Typo:
        @staticmethod
        @hookimpl
        def gns_processor():
            return []

    manager = _manager()
    manager.register(Typo, name="typo")
    with pytest.raises(pluggy.PluginValidationError, match="unknown hook 'gns_processor'"):
        manager.check_pending()


def test_each_hook_is_typed_with_what_it_returns():
    """A plugin author's type checker sees ``list[type[Processor]]``, not ``list[type]``."""
    import typing

    from gns_framework import plugin_types

    names = {cls.__name__: cls for cls in COMPONENT_KINDS.values()}
    names.update(Metric=plugin_types.Metric, Command=plugin_types.Command)
    for kind, contract in COMPONENT_KINDS.items():
        hook = getattr(hookspecs, hookspecs.hook_of_kind(kind))
        assert typing.get_type_hints(hook, localns=names)["return"] == list[type[contract]], kind
    assert typing.get_type_hints(hookspecs.gns_metrics, localns=names)["return"] == list[plugin_types.Metric]
    assert typing.get_type_hints(hookspecs.gns_commands, localns=names)["return"] == list[plugin_types.Command]
