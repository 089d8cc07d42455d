"""Plugin discovery: entry points, duplicates, unknown names, broken plugins, disabling."""

from __future__ import annotations

import sys
import textwrap
import warnings

import pytest

from gns_framework.contracts import COMPONENT_KINDS, Params, Processor
from gns_framework.errors import PluginError, PluginWarning, RecipeError
from gns_framework.hookspecs import hookimpl
from gns_framework.plugins import DISABLE_ENV, load_registry

BUILTINS = {
    "graph_builder": {"radius"},
    "encoder": {"mlp"},
    "processor": {"interaction_network"},
    "decoder": {"mlp"},
    "integrator": {"semi_implicit_euler"},
    "dataset": {"safe", "npz"},
    "material": {"water", "sand", "goop", "rigid"},
}


def test_builtins_come_from_entry_points_of_this_distribution(registry):
    for kind, names in BUILTINS.items():
        assert names <= set(registry.names(kind)), kind
        for name in names:
            entry = registry.entry(kind, name)
            assert entry.distribution == "gns-framework"
            assert entry.plugin.startswith("builtin-")
            assert entry.source_file.endswith(".py")
            assert issubclass(entry.cls, COMPONENT_KINDS[kind])


class _OtherInteractionNetwork(Processor):
    name = "interaction_network"

    class Params(Params):
        pass

    def forward(self, node_latent, edge_latent, graph):
        return node_latent, edge_latent


class _DuplicatePlugin:
    @staticmethod
    @hookimpl
    def gns_processors():
        return [_OtherInteractionNetwork]


def test_duplicate_names_are_an_error_naming_both_providers():
    with pytest.raises(PluginError) as info:
        load_registry(plugins=[("my-dup", _DuplicatePlugin)])
    message = str(info.value)
    assert "interaction_network" in message
    assert "builtin-processors" in message and "gns-framework" in message
    assert "my-dup" in message
    assert f"{DISABLE_ENV}=my-dup (or {DISABLE_ENV}=builtin-processors)" in message


def test_unknown_name_lists_choices_with_did_you_mean(registry):
    with pytest.raises(PluginError) as info:
        registry.get("processor", "interaction_netwrok")
    assert "did you mean 'interaction_network'" in str(info.value)
    assert "interaction_network" in str(info.value).split("installed: ")[1].split(", ")


def test_hook_returning_a_non_component_names_the_plugin():
    class Bad:
        @staticmethod
        @hookimpl
        def gns_encoders():
            return [dict]

    with pytest.raises(PluginError, match=r"plugin 'bad-plugin'.*not a subclass of Encoder"):
        load_registry(plugins=[("bad-plugin", Bad)])


def test_material_type_clash_names_both():
    from gns_framework.contracts import Material

    class Mud(Material):
        name = "mud"
        particle_type = 5

    class MudPlugin:
        @staticmethod
        @hookimpl
        def gns_materials():
            return [Mud]

    with pytest.raises(PluginError, match=r"'water'.*'mud'.*particle type 5") as info:
        load_registry(plugins=[("mud", MudPlugin)])
    message = str(info.value)
    assert "builtin-materials" in message and "plugin 'mud'" in message
    assert (
        f"disable its plugin with the environment variable {DISABLE_ENV}=mud (or {DISABLE_ENV}=builtin-materials)"
        in message
    )


@pytest.fixture
def broken_distribution(tmp_path, monkeypatch):
    """An installed distribution whose entry point imports a module that raises."""
    dist = tmp_path / "broken_gns_plugin-1.2.3.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-gns-plugin\nVersion: 1.2.3\n")
    (dist / "entry_points.txt").write_text("[gns_framework]\nbroken = broken_gns_module\n")
    (tmp_path / "broken_gns_module.py").write_text(textwrap.dedent("raise ImportError('missing dependency xyz')\n"))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("broken_gns_module", None)


def test_a_broken_plugin_is_skipped_with_one_warning_naming_it(broken_distribution):
    with pytest.warns(PluginWarning) as caught:
        registry = load_registry()
    (warning,) = [w for w in caught if issubclass(w.category, PluginWarning)]
    message = str(warning.message)
    assert "entry point 'broken' = 'broken_gns_module' of distribution broken-gns-plugin 1.2.3" in message
    assert "failed to load and was skipped: ImportError: missing dependency xyz" in message
    assert f"{DISABLE_ENV}=broken" in message and "\n" not in message
    assert "interaction_network" in registry.names("processor")  # the other plugins still load
    assert [b.entry_point for b in registry.broken] == ["broken"]
    assert (
        registry.broken_of("broken-gns-plugin") == list(registry.broken) and registry.broken_of("gns-framework") == []
    )


def test_a_missing_component_names_the_broken_plugin_that_may_provide_it(broken_distribution):

    with pytest.warns(PluginWarning):
        registry = load_registry()
    with pytest.raises(RecipeError) as info:
        registry.resolve("processor", {"name": "broken_processor"}, ("model", "processor"), "recipe.yaml")
    ((location, message),) = info.value.problems
    assert location == "model.processor.name" and message.startswith("unknown processor 'broken_processor'")
    assert "it may be provided by a plugin that was skipped: plugin entry point 'broken'" in message
    assert "broken-gns-plugin 1.2.3, which failed to load (ImportError: missing dependency xyz)" in message


def test_a_registry_without_broken_plugins_adds_no_note(registry):
    with pytest.raises(PluginError) as info:
        registry.get("processor", "nothing_like_it")
    assert "skipped" not in str(info.value) and registry.broken == ()


def test_environment_variable_disables_plugins(broken_distribution, monkeypatch):
    monkeypatch.setenv(DISABLE_ENV, "broken,builtin-materials")
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginWarning)  # the broken plugin is never loaded, so never warned about
        registry = load_registry()
    # Installed third-party materials (the example clay) stay; the built-in ones are gone.
    assert all(entry.plugin != "builtin-materials" for entry in registry.entries("material"))
    assert "interaction_network" in registry.names("processor")


def test_disabling_a_name_that_matches_no_plugin_warns_once_with_the_names_that_exist(monkeypatch):
    from gns_framework.cli.commands import load_commands

    monkeypatch.setenv(DISABLE_ENV, "builtin-material,builtin-encoders,gns-frame")
    with pytest.warns(PluginWarning) as caught:
        load_commands()  # gns builds the commands' manager too, in the same process: it does not warn again
        registry = load_registry()
    messages = [str(w.message) for w in caught if issubclass(w.category, PluginWarning)]
    assert len(messages) == 1, messages  # builtin-encoders exists and is disabled without a word
    message = messages[0]
    assert message.startswith(
        f"{DISABLE_ENV}: 'builtin-material' (did you mean 'builtin-materials'?), 'gns-frame' (did you mean "
        "'gns-framework'?) name no installed plugin, so nothing was disabled for them; installed plugins"
    )
    listed = dict(item.split(": ", 1) for item in message.split("either name disables): ")[1].split("; "))
    assert {"builtin-materials", "builtin-processors", "builtin-metrics"} <= set(listed["gns-framework"].split(", "))
    assert listed["gns-example-clay"] == "example-clay"
    assert "water" in registry.names("material") and registry.names("encoder") == []


def test_a_command_plugin_can_be_disabled_without_a_warning(tmp_path, monkeypatch):
    """Its name is an entry point of the commands' group only; the components' manager knows it too."""
    dist = tmp_path / "sieve_commands-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: sieve-commands\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[gns_framework.commands]\nsieve = sieve_commands_module\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv(DISABLE_ENV, "sieve")
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginWarning)
        load_registry()


def test_registries_are_independent():
    first = load_registry(plugins=[("extra", _DuplicatePlugin)], load_entry_points=False)
    second = load_registry(load_entry_points=False)
    assert first.names("processor") == ["interaction_network"]
    assert second.names("processor") == []


# --- metric and command hooks -----------------------------------------------------------------------


def _metric_plugin(*metrics):
    class MetricPlugin:
        @staticmethod
        @hookimpl
        def gns_metrics():
            return list(metrics)

    return MetricPlugin


def test_metric_clashes_and_non_records_name_the_plugin():
    from gns_framework.plugin_types import Metric

    twin = Metric("sinkhorn_final", "L, another", lambda pair: None)
    with pytest.raises(PluginError, match=r"two metrics are named 'sinkhorn_final'.*builtin-metrics.*twin-metric"):
        load_registry(plugins=[("twin-metric", _metric_plugin(twin))])
    with pytest.raises(PluginError, match=r"plugin 'bad-metric'.*not a gns_framework\.plugin_types\.Metric"):
        load_registry(plugins=[("bad-metric", _metric_plugin({"name": "x"}))])


def test_a_plugins_metric_can_be_tracked_in_validation_and_chosen_for_best_pt(tmp_path):
    from tiny import tiny_recipe_mapping

    from gns_framework.config.recipe import validate_recipe
    from gns_framework.plugin_types import Metric

    spread = Metric("spread_pct", "%, a plugin's measure", lambda pair: None, validation="spread_pct")
    registry = load_registry(plugins=[("spread-metric", _metric_plugin(spread))])
    tracked = registry.validation_metrics()
    assert tracked["valid_rollout_spread_pct"] is spread
    assert tracked["valid_rollout_deposit_error_pct"].name == "deposit_error_pct"
    raw = tiny_recipe_mapping(tmp_path)
    raw["training"]["best_metric"] = "valid_rollout_spread_pct"
    assert validate_recipe(raw, registry).training.best_metric == "valid_rollout_spread_pct"
    raw["training"]["best_metric"] = "valid_rollout_spread_pct_worst"
    assert validate_recipe(raw, registry).training.best_metric == "valid_rollout_spread_pct_worst"
    raw["training"]["best_metric"] = "valid_rollout_spread_pct"
    with pytest.raises(
        RecipeError,
        match=r"training.best_metric: unknown validation metric 'valid_rollout_spread_pct'.*"
        r"measured in validation: .*valid_rollout_deposit_error_pct",
    ):
        validate_recipe(raw, load_registry())
    twin = Metric("another_sinkhorn", "%, another", lambda pair: None, validation="sinkhorn_pct")
    with pytest.raises(
        PluginError,
        match=r"tracked in validation as valid_rollout_sinkhorn_pct: 'sinkhorn_final_pct' "
        r"from plugin 'builtin-metrics'.*'another_sinkhorn' from plugin 'twin-tracked'",
    ):
        load_registry(plugins=[("twin-tracked", _metric_plugin(twin))])


def test_a_registry_without_metrics_says_how_to_get_them():
    with pytest.raises(PluginError, match=r"no metric is installed.*builtin-metrics"):
        load_registry(load_entry_points=False).metrics()


def test_kinematic_types_come_from_the_materials(registry):
    from gns_framework.contracts import Material

    class Ballast(Material):
        name = "ballast"
        particle_type = 11
        kinematic = True

    class BallastPlugin:
        @staticmethod
        @hookimpl
        def gns_materials():
            return [Ballast]

    assert registry.kinematic_types() == (3,)
    assert load_registry(plugins=[("ballast", BallastPlugin)]).kinematic_types() == (3, 11)


def test_resolve_gives_the_class_and_its_validated_params(registry):
    from gns_framework.specs import ComponentSpec

    cls, params = registry.resolve("processor", ComponentSpec(name="interaction_network", message_passing_steps=3))
    assert cls is registry.get("processor", "interaction_network")
    assert isinstance(params, cls.Params) and params.message_passing_steps == 3
    # A mapping as read from YAML resolves the same way.
    _, again = registry.resolve("processor", {"name": "interaction_network", "message_passing_steps": 3})
    assert again == params


def test_resolve_locates_an_unknown_name_and_each_bad_parameter(registry):
    from gns_framework.errors import RecipeError

    with pytest.raises(RecipeError) as unknown:
        registry.resolve("processor", {"name": "interaction_netwrok"}, ("model", "processor"), "recipe.yaml")
    ((location, message),) = unknown.value.problems
    assert unknown.value.source == "recipe.yaml" and location == "model.processor.name"
    assert "did you mean 'interaction_network'" in message and "installed:" in message
    with pytest.raises(RecipeError) as bad:
        registry.resolve(
            "processor",
            {"name": "interaction_network", "message_passing_steps": "many", "colour": 1},
            ("model", "processor"),
        )
    locations = dict(bad.value.problems)
    assert set(locations) == {"model.processor.message_passing_steps", "model.processor.colour"}


def test_only_the_registry_turns_names_into_validated_params():
    """Name -> Params validation lives in Registry.resolve; the conformance kit builds components from classes."""
    from pathlib import Path

    package = Path(__file__).resolve().parents[1] / "gns_framework"
    allowed = {package / "plugins.py", package / "testing.py"}
    elsewhere = [
        str(path.relative_to(package))
        for path in sorted(package.rglob("*.py"))
        if path not in allowed and ".Params.model_validate" in path.read_text()
    ]
    assert elsewhere == []


def test_free_particle_types_are_the_valid_ids_no_material_has(registry):
    from gns_framework.contracts import PARTICLE_TYPE_IDS

    free = registry.free_particle_types()
    taken = {e.cls.particle_type for e in registry.entries("material")}
    assert {3, 5, 6, 7, 8} <= taken and not taken & set(free)
    assert sorted(taken | set(free)) == list(PARTICLE_TYPE_IDS)
