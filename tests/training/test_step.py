"""Push-forward training: the model learns the next true frame from inputs its own rollout made."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from tiny import tiny_recipe, tiny_recipe_mapping, tiny_trainer

from gns_framework.errors import RecipeError


class Recording(torch.nn.Module):
    """Stands in for the DDP-wrapped model in the training step and keeps the batch it is given."""

    def __init__(self, simulator):
        super().__init__()
        self.simulator = simulator

    def forward(self, batch, noise):
        self.batch = batch
        return self.simulator(batch, noise)


def test_the_trained_step_sees_the_models_own_rollout_and_the_true_frame_after_it(
    dataset_2d, registry, tmp_path, monkeypatch
):
    recipe = tiny_recipe(dataset_2d, registry)
    recipe = recipe.model_copy(update={"training": recipe.training.model_copy(update={"pushforward_steps": 2})})
    trainer = tiny_trainer(recipe, tmp_path, registry)
    windows = trainer.windows.batch(trainer.order.draw(0).mine)
    assert windows.ahead.shape == (windows.num_particles, 2, 2)
    monkeypatch.setattr(trainer.optimisation, "pushforward_steps", lambda step: 2)
    recording = Recording(trainer.simulator)
    trainer.optimisation.model = recording
    with torch.no_grad():
        first = trainer.simulator.predict_next_position(windows, prescribed=windows.next_position)
        rolled = torch.cat([windows.position_sequence[:, 1:], first[:, None]], dim=1)
        second = trainer.simulator.predict_next_position(
            replace(windows, position_sequence=rolled), prescribed=windows.ahead[:, 0]
        )
    trainer.train_step()
    seen = recording.batch
    torch.testing.assert_close(seen.position_sequence[:, :-2], windows.position_sequence[:, 2:], rtol=0, atol=0)
    torch.testing.assert_close(seen.position_sequence[:, -2], first, rtol=0, atol=0)
    torch.testing.assert_close(seen.position_sequence[:, -1], second, rtol=0, atol=0)
    torch.testing.assert_close(seen.next_position, windows.ahead[:, 1], rtol=0, atol=0)
    assert not torch.equal(first, windows.next_position), "the model's step differs from the truth"
    trainer.close()


def test_the_unrolled_steps_are_drawn_per_step_within_the_bound(dataset_2d, registry, tmp_path):
    recipe = tiny_recipe(dataset_2d, registry)
    recipe = recipe.model_copy(update={"training": recipe.training.model_copy(update={"pushforward_steps": 3})})
    trainer = tiny_trainer(recipe, tmp_path, registry)
    drawn = [trainer.optimisation.pushforward_steps(step) for step in range(40)]
    assert set(drawn) == {0, 1, 2, 3}
    trainer.close()
    again = tiny_trainer(recipe, tmp_path / "again", registry)
    assert again.optimisation.pushforward_steps(7) == drawn[7], "a resumed run draws the same"
    again.close()


def test_a_negative_pushforward_is_refused_with_its_location(dataset_2d, registry):
    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"]["pushforward_steps"] = -1
    from gns_framework.config.recipe import validate_recipe

    with pytest.raises(RecipeError, match=r"training.pushforward_steps: Input should be greater than or equal to 0"):
        validate_recipe(raw, registry)
