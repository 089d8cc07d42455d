"""gns invert returns its best iterate (by the loss or by held-out frames), decays Adam's step if asked,
records the truth the data holds, and reads the paths of its config relative to the config file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from gns_framework.config.paths import resolve_named_path
from gns_framework.config.recipe import load_recipe
from gns_framework.errors import RecipeError
from gns_framework.inverse.config import load_invert_config, parse_invert_config
from gns_framework.inverse.optimize import Iterate, adam, best_iterate

ROOT = Path(__file__).resolve().parents[2]


def raw_config(**changes) -> dict:
    raw = {
        "model": "m.pt",
        "observed": {"dataset": "d", "frames": [8, 10]},
        "unknowns": {"friction": {"bounds": [0.4, 1.0]}},
        "optimizer": {"name": "adam", "lr": 0.05},
    }
    for key, value in changes.items():
        raw[key] = {**raw[key], **value}
    return raw


def test_lr_decay_and_held_out_frames_are_validated_with_their_location():
    config, _ = parse_invert_config(raw_config(optimizer={"lr_decay": 0.9}, observed={"held_out": [12]}), "x")
    assert config.optimizer.lr_decay == 0.9 and config.observed.held_out == [12]
    cases = [
        (
            raw_config(optimizer={"name": "lbfgs", "lr_decay": 0.9}),
            "optimizer",
            "lr_decay: only adam takes a step size",
        ),
        (raw_config(optimizer={"lr_decay": 0}), "optimizer.lr_decay", "greater than 0"),
        (raw_config(optimizer={"lr_decay": 1.5}), "optimizer.lr_decay", "less than or equal to 1"),
        (raw_config(observed={"held_out": [10, 12]}), "observed", "frames [10] are also in frames"),
        (raw_config(observed={"frames": "all", "held_out": [12]}), "observed", "leaves no frame to hold out"),
    ]
    for raw, location, message in cases:
        with pytest.raises(RecipeError) as caught:
            parse_invert_config(raw, "inv.yaml")
        assert any(loc == location and message in text for loc, text in caught.value.problems), caught.value.problems


def test_adam_decays_its_step_size():
    def loss(u):
        return (u - 0.3).abs().sum()  # constant gradient: Adam's steps are its step size

    def path(decay):
        seen = []
        adam(loss, np.array([0.9]), 0.05, 6, lambda it: seen.append(float(it.u[0])), lambda u: "", torch.float64, decay)
        return -np.diff(seen)

    np.testing.assert_allclose(path(None), 0.05, rtol=1e-6)
    np.testing.assert_allclose(path(0.5), 0.05 * 0.5 ** np.arange(5), rtol=1e-6)


def test_the_best_iterate_is_chosen_by_the_held_out_misfit_when_there_is_one():
    u = np.zeros(1)
    by_loss = [Iterate(1, 3.0, u), Iterate(2, 1.0, u), Iterate(3, 2.0, u)]
    assert best_iterate(by_loss).iteration == 2
    held_out = [Iterate(1, 3.0, u, 0.5), Iterate(2, 1.0, u, 0.9), Iterate(3, 2.0, u, 0.7)]
    assert best_iterate(held_out).iteration == 1


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


@pytest.mark.parametrize("path", sorted((ROOT / "inversions").glob("*.yaml")))
def test_the_shipped_inversions_name_their_model_relative_to_themselves(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config, _ = load_invert_config(path)
    assert Path(config.model).resolve().is_file() and Path(config.model).resolve().parent == ROOT / "models"
    assert Path(config.observed.dataset).resolve().parent == ROOT / "data"


@pytest.mark.parametrize("held_out", [False, True])
def test_gns_invert_returns_its_best_iterate(tmp_path, tiny_model, dataset_multimaterial, held_out):
    configs = tmp_path / "configs"
    configs.mkdir()
    os.symlink(tiny_model, configs / "model.pt")
    os.symlink(dataset_multimaterial, tmp_path / "observed")
    raw = {
        "model": "model.pt",  # beside the config
        "observed": {"dataset": "../observed", "split": "test", "trajectory": 0, "frames": [8, 10, 12]},
        "unknowns": {"friction": {"bounds": [0.4, 1.0], "initial": 0.95}},
        "optimizer": {"name": "adam", "lr": 0.3, "iterations": 6, "lr_decay": 0.8},
        "loss": "positions",
        "checkpoint_every": 3,
        "threads": 1,
    }
    if held_out:
        raw["observed"]["held_out"] = [14, 16]
    (configs / "inv.yaml").write_text(yaml.safe_dump(raw))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "gns_framework.cli",
            "invert",
            str(configs / "inv.yaml"),
            "--out",
            "out",
            "--no-progress",
            "--no-tracking",
            "--no-gif",
            "--outside-envelope",
        ],
        capture_output=True,
        text=True,
        cwd=elsewhere,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    record = json.loads((elsewhere / "out" / "result.json").read_text())
    rows = [json.loads(line) for line in (elsewhere / "out" / "metrics.jsonl").read_text().splitlines()]
    rows = [row for row in rows if "friction" in row]
    assert [row["step"] for row in rows][:6] == [1, 2, 3, 4, 5, 6]
    score = "held_out_loss" if held_out else "loss"
    best = min(rows, key=lambda row: row[score])
    assert record["best_iteration"] == best["step"] and record["selected_by"] == ("held_out" if held_out else "loss")
    assert record["loss"] == pytest.approx(best["loss"]) and record["unknowns"]["friction"] == pytest.approx(
        best["friction"]
    )
    assert record["last"]["iteration"] == rows[-1]["step"]
    assert all(record.get("held_out_loss", record["loss"]) <= row[score] for row in rows)
    # The synthetic data holds its friction in its property column: the truth, and the error of both answers.
    truth = record["truth"]["friction"]
    assert record["error_pct"]["friction"] == pytest.approx(100 * abs(record["unknowns"]["friction"] - truth) / truth)
    assert "error_pct" in record["last"] and "unknowns.friction.bounds" in record["outside_envelope"][0]
    assert f"iteration {record['best_iteration']}" in done.stdout and "error" in done.stdout
    assert (elsewhere / "out" / "convergence.png").stat().st_size > 0
