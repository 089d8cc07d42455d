"""A folder laid out like the repository in which a document's commands run without touching it.

The recipes, scenes, inversion configs, models, benchmarks and scripts are copied
(a command may write into models/, as a reproduction's ``cp`` does); data and runs are
made there by the commands themselves. The copies of recipes and inversion configs are
scaled down (a few training steps, validation and checkpoints every two, two
optimiser iterations, scenes of at most 60 frames) unless ``GNS_DOCS_SCALE=full``; ``gns``, ``python`` and
``torchrun`` are :mod:`shim` (first on PATH and at ``.venv/bin/``).
"""

from __future__ import annotations

import os
import shutil
import stat
import sys
from pathlib import Path

import yaml
from doc_blocks import ROOT

SCENE_FRAMES = 60
"""Frames of a scaled-down scene: 0.15-0.3 s of motion, past a learned model's 6 input frames at stride 2."""
COPIED = ("recipes", "scenes", "inversions", "models", "benchmarks", "scripts")
SHIMMED = ("gns", "python", "python3", "torchrun")
SHIM = Path(__file__).resolve().parent / "shim.py"
SETUP_STUB = """#!/usr/bin/env bash
# docs-test: the set-up CI runs before the tests (.ci/run); not run a second time here.
echo "docs-test: not run here: bash scripts/setup.sh (CI ran it before the tests)"
"""


def full_scale() -> bool:
    return os.environ.get("GNS_DOCS_SCALE", "ci") == "full"


def _scale_recipe(path: Path) -> None:
    recipe = yaml.safe_load(path.read_text(encoding="utf-8"))
    training = recipe.get("training") if isinstance(recipe, dict) else None
    if not isinstance(training, dict):
        return
    training["steps"] = min(int(training.get("steps", 4)), 4)
    training.update(validate_every=2, checkpoint_every=2, log_every=1)
    if "validation_rollouts" in training:
        training["validation_rollouts"] = 1
    path.write_text(yaml.safe_dump(recipe, sort_keys=False), encoding="utf-8")


def _scale_scene(path: Path) -> None:
    scene = yaml.safe_load(path.read_text(encoding="utf-8"))
    timing = scene.get("time") if isinstance(scene, dict) else None
    if isinstance(timing, dict) and "frames" in timing:
        timing["frames"] = min(int(timing["frames"]), SCENE_FRAMES)
        path.write_text(yaml.safe_dump(scene, sort_keys=False), encoding="utf-8")


def _scale_inversion(path: Path) -> None:
    config = yaml.safe_load(path.read_text(encoding="utf-8"))
    config.setdefault("optimizer", {})["iterations"] = 2
    config["checkpoint_every"] = 1
    path.write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")


def _executable(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")
    path.chmod(path.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)


def make_sandbox(folder: Path, log: Path, data_cache: Path) -> dict[str, str]:
    """Lay out ``folder``; the environment its commands run with."""
    for name in COPIED:
        shutil.copytree(ROOT / name, folder / name, ignore=shutil.ignore_patterns("__pycache__", "in_training"))
    (folder / "docs" / "images").mkdir(parents=True)
    if not full_scale():
        for recipe in (folder / "recipes").rglob("*.yaml"):
            _scale_recipe(recipe)
        for scene in (folder / "scenes").rglob("*.yaml"):
            _scale_scene(scene)
        for config in (folder / "inversions").glob("*.yaml"):
            _scale_inversion(config)
    _executable(folder / "scripts" / "setup.sh", SETUP_STUB)
    shims = folder / ".shims"
    for place in (shims, folder / ".venv" / "bin"):
        place.mkdir(parents=True)
        for tool in SHIMMED:
            name = "python" if tool == "python3" else tool
            _executable(place / tool, f'#!/bin/sh\nexec "{sys.executable}" "{SHIM}" {name} "$@"\n')
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MLFLOW_", "PYTEST_"))}
    env.update(
        PATH=f"{shims}{os.pathsep}{env.get('PATH', '')}",
        GNS_DOCS_PYTHON=sys.executable,
        GNS_DOCS_REPO=str(ROOT),
        GNS_DOCS_LOG=str(log),
        GNS_DOCS_DATA_CACHE=str(data_cache),
        OMP_NUM_THREADS="1",
        MPLBACKEND="Agg",
    )
    return env
