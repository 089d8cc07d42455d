"""A checkpoint records the distribution of each component; loading one whose component is missing says what
to install."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
from tiny import tiny_recipe, tiny_trainer

from gns_framework.assembly.trained import load_trained
from gns_framework.errors import CheckpointError, PluginWarning, RecipeError
from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint, save_checkpoint
from gns_framework.plugins import load_registry

FOO_MODULE = """
from gns_framework.contracts import Processor
from gns_framework.hookspecs import hookimpl
from gns_framework.layers import NormedMLP


class Foo(Processor):
    name = "foo"

    def __init__(self, params, sizes):
        super().__init__(params, sizes)
        self.node_mlp = NormedMLP(sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)

    def forward(self, node_latent, edge_latent, graph):
        return node_latent + self.node_mlp(node_latent), edge_latent


@hookimpl
def gns_processors():
    return [Foo]
"""


def install(folder: Path, version: str, module: str, source: str) -> Path:
    """A distribution gns-foo ``version`` in ``folder`` (to put on sys.path) whose entry point ``foo`` is ``module``."""
    dist = folder / f"gns_foo-{version}.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: gns-foo\nVersion: {version}\n")
    (dist / "entry_points.txt").write_text(f"[gns_framework]\nfoo = {module}\n")
    (folder / f"{module}.py").write_text(source)
    return folder


@pytest.fixture(scope="module")
def foo_checkpoint(dataset_2d, tmp_path_factory) -> Path:
    """A checkpoint trained with processor 'foo' of gns-foo 1.2.0, installed while it trained."""
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(install(tmp_path_factory.mktemp("site"), "1.2.0", "gns_foo", FOO_MODULE)))
        registry = load_registry()
        run = tmp_path_factory.mktemp("run")
        trainer = tiny_trainer(tiny_recipe(dataset_2d, registry, processor={"name": "foo"}), run, registry)
        trainer.train(1)
        trainer.close()
        path = list_checkpoints(run / "checkpoints")[-1][1]
        assert load_trained(path, registry).simulator.processor.name == "foo"  # loads while installed
    sys.modules.pop("gns_foo", None)
    return path


def test_the_checkpoint_records_each_components_distribution_and_version(foo_checkpoint):
    record = load_checkpoint(foo_checkpoint)["plugins"]
    assert record["processor/foo"] == {"distribution": "gns-foo", "version": "1.2.0", "plugin": "foo"}
    assert record["encoder/mlp"]["distribution"] == "gns-framework"


def test_a_component_whose_distribution_is_not_installed_says_what_to_pip_install(foo_checkpoint):
    with pytest.raises(CheckpointError) as info:
        load_trained(foo_checkpoint, load_registry())
    assert str(info.value) == (
        f"{foo_checkpoint}: plugins: needs processor 'foo' from distribution 'gns-foo' 1.2.0, which is not "
        "installed: pip install gns-foo==1.2.0"
    )


def test_another_version_without_the_component_says_which_is_installed(foo_checkpoint, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(install(tmp_path, "1.1.0", "gns_foo_old", "")))
    with pytest.raises(
        CheckpointError,
        match=re.escape(
            "needs processor 'foo' from distribution 'gns-foo' 1.2.0; 1.1.0 is installed, which has no processor "
            "'foo': pip install gns-foo==1.2.0"
        ),
    ):
        load_trained(foo_checkpoint, load_registry())


def test_a_distribution_whose_plugin_fails_to_load_names_the_plugin_and_its_exception(
    foo_checkpoint, tmp_path, monkeypatch
):
    monkeypatch.syspath_prepend(str(install(tmp_path, "1.2.0", "gns_foo_broken", "raise ImportError('no libfoo')\n")))
    with pytest.warns(PluginWarning):
        registry = load_registry()
    with pytest.raises(CheckpointError) as info:
        load_trained(foo_checkpoint, registry)
    assert str(info.value) == (
        f"{foo_checkpoint}: plugins: needs processor 'foo' from distribution 'gns-foo' 1.2.0, whose plugin failed "
        "to load and was skipped: plugin entry point 'foo' = 'gns_foo_broken' (ImportError: no libfoo)"
    )
    sys.modules.pop("gns_foo_broken", None)


def test_a_checkpoint_recorded_before_distributions_were_keeps_the_stored_recipes_message(foo_checkpoint, tmp_path):
    """Its record is one ``"distribution version"`` string per component: the stored recipe names what is missing."""
    state = load_checkpoint(foo_checkpoint)
    state["plugins"] = {key: f"{value['distribution']} {value['version']}" for key, value in state["plugins"].items()}
    old = save_checkpoint(tmp_path / "old.pt", {k: v for k, v in state.items() if k != "format"})
    with pytest.raises(RecipeError) as info:
        load_trained(old, load_registry())
    ((location, message),) = info.value.problems
    assert info.value.source == f"{old} (stored recipe)" and location == "model.processor.name"
    assert message.startswith("unknown processor 'foo'")


def test_a_stored_deposit_warning_is_loaded_and_a_broken_one_named(tmp_path):
    from synthetic import write_synthetic_dataset
    from tiny import with_deposit_warning

    data = write_synthetic_dataset(tmp_path / "data", train=1, valid=1, test=1, frames=12)
    trainer = tiny_trainer(tiny_recipe(data), tmp_path / "run")
    plain = trainer.checkpoints.save()
    trainer.close()
    assert load_trained(plain, load_registry()).deposit_warning is None
    warned = with_deposit_warning(plain, tmp_path / "warned.pt", threshold=0.25)
    assert load_trained(warned, load_registry()).deposit_warning.threshold == 0.25
    state = load_checkpoint(warned, map_location="cpu")
    state.pop("format")
    state["deposit_warning"]["weights"] = [1.0]
    broken = save_checkpoint(tmp_path / "broken.pt", state)
    with pytest.raises(CheckpointError, match=r"broken.pt: deposit_warning: not a warning record \(.*one value per"):
        load_trained(broken, load_registry())
