"""The weight average: the exponential average of the weights by hand, state round trip, first update copies."""

from __future__ import annotations

import pytest
import torch

from gns_framework.training.ema import WeightAverage


def test_the_average_follows_the_recursion_and_leaves_the_model_alone():
    model = torch.nn.Linear(3, 2)
    average = WeightAverage(model, decay=0.9)
    history = []
    for step in range(5):
        with torch.no_grad():
            model.weight.add_(step + 1.0)
        history.append(model.weight.detach().clone())
        average.update(model)
    expected = history[0].double()
    for weights in history[1:]:
        expected = 0.9 * expected + 0.1 * weights.double()
    torch.testing.assert_close(average.module.weight.double(), expected, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(model.weight, history[-1])
    assert not torch.allclose(average.module.weight, model.weight)


def test_state_round_trip_resumes_the_same_average():
    model = torch.nn.Linear(3, 2)
    first = WeightAverage(model, decay=0.99)
    for _ in range(3):
        with torch.no_grad():
            model.weight.mul_(1.1)
        first.update(model)
    second = WeightAverage(torch.nn.Linear(3, 2), decay=0.99)
    second.load_state_dict(first.state_dict())
    with torch.no_grad():
        model.weight.add_(1.0)
    first.update(model)
    second.update(model)
    assert torch.equal(first.module.weight, second.module.weight)
    assert first.state_dict()["updates"] == 4


@pytest.mark.parametrize("decay", [0.0, 1.0, -0.5])
def test_a_decay_outside_the_open_interval_is_refused(decay):
    with pytest.raises(ValueError, match="ema_decay must lie in"):
        WeightAverage(torch.nn.Linear(1, 1), decay)


def test_a_run_with_a_weight_average_validates_ships_and_resumes_it(dataset_2d, tmp_path):
    """best.pt and rollouts use the average; a resume continues it exactly; without it nothing changes."""
    from tiny import tiny_recipe_mapping, tiny_trainer

    from gns_framework.assembly.trained import load_trained
    from gns_framework.config.recipe import validate_recipe
    from gns_framework.io.checkpoint import load_checkpoint
    from gns_framework.plugins import load_registry

    registry = load_registry()
    raw = tiny_recipe_mapping(dataset_2d, lr=1e-2)
    raw["training"].update(steps=6, ema_decay=0.5, checkpoint_every=3)
    recipe = validate_recipe(raw, registry)
    trainer = tiny_trainer(recipe, tmp_path / "run", registry)
    trainer.train()
    trainer.close()
    state = load_checkpoint(tmp_path / "run" / "checkpoints" / "checkpoint-000000006.pt")
    assert state["ema"]["updates"] == 6
    raw_weights, averaged = state["model"], state["ema"]["model"]
    assert any(not torch.equal(raw_weights[k], averaged[k]) for k in raw_weights if raw_weights[k].is_floating_point())
    loaded = load_trained(tmp_path / "run" / "checkpoints" / "checkpoint-000000006.pt", registry)
    for name, value in loaded.simulator.state_dict().items():
        assert torch.equal(value, averaged[name]), name

    resumed = tiny_trainer(recipe, tmp_path / "resumed", registry)
    resumed.checkpoints.resume(tmp_path / "run" / "checkpoints" / "checkpoint-000000003.pt")
    resumed.train()
    resumed.close()
    again = load_checkpoint(tmp_path / "resumed" / "checkpoints" / "checkpoint-000000006.pt")
    for name, value in averaged.items():
        assert torch.equal(again["ema"]["model"][name], value), name
