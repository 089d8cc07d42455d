"""Paths named inside a file (``gns_framework.config.paths``): beside the file first, then from the working
directory for older files, absolute as written, ``~`` expanded; what exists nowhere is kept beside the file or as
named. The recipe's ``dataset.path`` follows the same rule."""

from __future__ import annotations

from pathlib import Path

import yaml

from gns_framework.config.paths import resolve_named_path
from gns_framework.config.recipe import load_recipe

ROOT = Path(__file__).resolve().parents[2]


def test_named_paths_resolve_beside_their_file_then_from_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "beside").mkdir()
    (tmp_path / "here").mkdir()
    source = tmp_path / "configs" / "x.yaml"
    monkeypatch.chdir(tmp_path)
    assert resolve_named_path("beside", source) == Path("configs/beside")
    assert resolve_named_path("here", source) == Path("here")  # an older, working-directory-relative file
    assert resolve_named_path("nowhere", source) == Path("configs/nowhere")  # named in the error beside the file
    assert resolve_named_path("nowhere", source, missing="as_named") == Path("nowhere")  # a recipe's data not made yet
    assert resolve_named_path(tmp_path / "here", source) == tmp_path / "here"
    monkeypatch.chdir(tmp_path / "here")
    assert resolve_named_path("beside", source) == tmp_path / "configs" / "beside"


def test_a_home_path_is_expanded_and_used_as_it_is(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    # Absolute once expanded: used as it is, never looked for beside the file.
    assert resolve_named_path("~/data", tmp_path / "x.yaml") == tmp_path / "home" / "data"


def test_without_a_file_a_path_is_taken_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_named_path("data/d", None) == Path("data/d")


def test_a_path_outside_the_working_directory_is_recorded_absolute(tmp_path, monkeypatch):
    (tmp_path / "configs" / "beside").mkdir(parents=True)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    assert resolve_named_path("beside", tmp_path / "configs" / "x.yaml") == tmp_path / "configs" / "beside"
    # ".." in what the file names is resolved away: the recorded path is one plain absolute path.
    assert resolve_named_path("../configs/beside", tmp_path / "configs" / "x.yaml") == tmp_path / "configs" / "beside"


def test_a_recipe_reads_its_dataset_beside_it_from_any_working_directory(tmp_path, monkeypatch, registry):
    recipe_file = ROOT / "recipes" / "sand2d_fast.yaml"
    copy = tmp_path / "recipes" / "fast.yaml"
    copy.parent.mkdir()
    raw = yaml.safe_load(recipe_file.read_text())
    raw["dataset"]["path"] = "../data/demo"
    copy.write_text(yaml.safe_dump(raw))
    (tmp_path / "data" / "demo").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "recipes")
    assert Path(load_recipe("fast.yaml", registry).dataset.path) == Path("../data/demo").resolve()
    monkeypatch.chdir(ROOT)  # the shipped recipes name data/... from the repository root, as before
    assert load_recipe(recipe_file, registry).dataset.path == "data/demo_sand_2d"
    assert load_recipe(recipe_file, registry, {"dataset": {"path": "elsewhere"}}).dataset.path == "elsewhere"
