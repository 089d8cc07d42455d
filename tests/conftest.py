"""Shared fixtures: an isolated registry and small synthetic datasets made in-process."""

from __future__ import annotations

from pathlib import Path

import pytest

from gns_framework.demo.soft_spheres import write_synthetic_dataset
from gns_framework.plugins import load_registry

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def registry():
    return load_registry()


@pytest.fixture(scope="session")
def dataset_2d(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "synthetic2d", train=4, valid=2, test=1)


@pytest.fixture(scope="session")
def dataset_multimaterial(tmp_path_factory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("data") / "multimaterial2d",
        train=2,
        valid=1,
        test=1,
        particle_types=(5, 6),
        kinematic_floor=True,
        with_property=True,
        frames=20,
    )


@pytest.fixture(scope="session")
def small_recipe():
    """Builds a fast recipe mapping (tiny model) for tests that only need the machinery."""
    return _small_recipe


def _small_recipe(dataset: Path, run_dir: Path, **model) -> dict:
    return {
        "name": "test",
        "seed": 0,
        "output_dir": str(run_dir),
        "dataset": {"name": "safe", "path": str(dataset)},
        "model": {"latent_size": 16, "mlp_hidden_size": 16, "type_embedding_size": 4,
                  "processor": {"name": "interaction_network", "message_passing_steps": 2}, **model},
        "training": {"steps": 6, "log_every": 2, "validate_every": 3, "checkpoint_every": 3, "validation_windows": 4},
    }
