"""``gns generate`` (``gns_framework.cli.generate``): what the command changes in the scene before simulating it
(``--seed``, ``--device``), a read-only layout refused before anything is written, and which earlier folders count
as its own. Writing, reusing and seeding datasets end to end, and the split counts, are tested in
tests/ground_truth/test_generate.py; refusing other folders in tests/test_no_silent_overwrite.py."""

from __future__ import annotations

import json

import pytest
import yaml
from scene_builders import mixed

from gns_framework.cli import generate as generate_command
from gns_framework.cli import main
from gns_framework.errors import GnsError


class Stop(GnsError):
    """Raised by the stand-in simulator builder: the test has seen the scene; nothing is simulated."""


@pytest.fixture
def scene_file(tmp_path):
    raw = mixed(frames=6)
    raw["seed"] = 4
    raw["simulator"] = {"name": "mls_mpm", "cfl": 0.4}
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture
def built(monkeypatch, sim_registry):
    """The scenes the command builds its simulator for."""
    scenes = []

    def build(scene, registry, source):
        scenes.append(scene)
        raise Stop("seen")

    monkeypatch.setattr(generate_command, "load_registry", lambda: sim_registry)
    monkeypatch.setattr(generate_command, "build_ground_truth_simulator", build)
    return scenes


def test_seed_and_device_override_the_scene_file_and_keep_its_simulator_parameters(scene_file, built, tmp_path):
    common = ["generate", str(scene_file), "--trajectories", "3", "--out", str(tmp_path / "d"), "--no-progress"]
    assert main(common) == 2
    assert main([*common, "--seed", "11", "--device", "cuda:1"]) == 2
    as_written, changed = built
    assert as_written.seed == 4 and "device" not in as_written.simulator.params
    assert changed.seed == 11
    assert changed.simulator.name == "mls_mpm"
    assert changed.simulator.params == {"cfl": 0.4, "device": "cuda:1"}
    assert not (tmp_path / "d").exists()


class ReadOnly:
    writable = False


class WithReadOnlyLayout:
    """The installed components plus a read-only dataset layout, ``archive``."""

    def __init__(self, registry):
        self.registry = registry

    def get(self, kind, name):
        return ReadOnly if (kind, name) == ("dataset", "archive") else self.registry.get(kind, name)

    def names(self, kind):
        return [*self.registry.names(kind), "archive"] if kind == "dataset" else self.registry.names(kind)


def test_a_read_only_layout_is_refused_naming_the_writable_ones(
    scene_file, monkeypatch, sim_registry, tmp_path, capsys
):
    monkeypatch.setattr(generate_command, "load_registry", lambda: WithReadOnlyLayout(sim_registry))
    monkeypatch.setattr(generate_command, "build_ground_truth_simulator", lambda scene, registry, source: object())
    out = tmp_path / "d"
    args = ["generate", str(scene_file), "--trajectories", "3", "--out", str(out), "--layout", "archive"]
    assert main(args) == 2
    writable = ", ".join(name for name in sim_registry.names("dataset"))  # every built-in layout writes
    assert capsys.readouterr().err == (
        f"gns generate: error: dataset layout 'archive' is read-only; writable: {writable}\n"
    )
    assert not out.exists()


def test_a_folder_is_its_own_when_its_metadata_records_what_it_was_generated_from(tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    assert not generate_command._generated(folder)  # no metadata.json
    (folder / "metadata.json").write_text(json.dumps({"dim": 2, "generated_from": {"scene": {"name": "x"}}}))
    assert generate_command._generated(folder)
    (folder / "metadata.json").write_text(json.dumps({"dim": 2}))  # a dataset from elsewhere
    assert not generate_command._generated(folder)
    for text in ("not json", '["generated_from"]'):
        (folder / "metadata.json").write_text(text)
        assert not generate_command._generated(folder)
