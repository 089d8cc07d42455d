"""The example processor package adds a processor through entry points only; one recipe line selects it and a model
trains with it, and its checkpoint names the distribution to install."""

from __future__ import annotations

import numpy as np
import pytest
from tiny import tiny_recipe, tiny_trainer

from gns_framework.assembly.trained import load_trained
from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint
from gns_framework.plugins import load_registry

pytest.importorskip("gns_example_processor", reason="install it: pip install -e plugins/examples/gns-processor")


def test_trains_with_the_example_processor_selected_by_one_recipe_line(dataset_2d, tmp_path):
    from gns_example_processor import MeanInteractionNetwork

    recipe = tiny_recipe(dataset_2d, processor={"name": "mean_interaction_network", "message_passing_steps": 2})
    trainer = tiny_trainer(recipe, tmp_path)
    assert isinstance(trainer.simulator.processor, MeanInteractionNetwork)
    losses = trainer.train(6)
    trainer.close()
    assert np.isfinite(losses).all() and np.mean(losses[-2:]) < np.mean(losses[:2])
    checkpoint = list_checkpoints(tmp_path / "checkpoints")[-1][1]
    record = load_checkpoint(checkpoint)["plugins"]["processor/mean_interaction_network"]
    assert record == {"distribution": "gns-example-processor", "version": "0.1.0", "plugin": "example-processor"}
    assert isinstance(load_trained(checkpoint, load_registry()).simulator.processor, MeanInteractionNetwork)
