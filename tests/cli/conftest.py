"""The tiny model the `gns invert` tests (test_invert.py) invert with, trained once for all of them."""

from __future__ import annotations

from pathlib import Path

import pytest
from tiny import tiny_recipe, tiny_trainer


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory, dataset_multimaterial, registry) -> Path:
    run = tmp_path_factory.mktemp("invert_run")
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial, registry), run, registry)
    trainer.train()
    return trainer.checkpoints.save()
