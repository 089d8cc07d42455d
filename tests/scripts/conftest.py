"""A tiny model trained two steps on the synthetic multimaterial data: the checkpoint the envelope scripts edit."""

from __future__ import annotations

import pytest
from tiny import tiny_recipe, tiny_trainer


@pytest.fixture(scope="module")
def trained(dataset_multimaterial, tmp_path_factory):
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial), tmp_path_factory.mktemp("run"))
    trainer.train(2)
    path = trainer.checkpoints.save()
    trainer.close()
    return path
