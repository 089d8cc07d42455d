"""Push-forward training and the unrolled loss: the model learns true frames from inputs its own rollout made."""

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

    def forward(self, batch, noise, unrolled_steps=0):
        self.batch, self.unrolled_steps = batch, unrolled_steps
        return self.simulator(batch, noise, unrolled_steps)


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


def with_training(recipe, **update):
    return recipe.model_copy(update={"training": recipe.training.model_copy(update=update)})


def test_the_unrolled_loss_is_taken_after_the_push_forward_on_the_true_frames_that_follow(
    dataset_2d, registry, tmp_path, monkeypatch
):
    recipe = with_training(tiny_recipe(dataset_2d, registry), pushforward_steps=1, unrolled_loss_steps=2)
    trainer = tiny_trainer(recipe, tmp_path, registry)
    windows = trainer.windows.batch(trainer.order.draw(0).mine)
    assert windows.ahead.shape == (windows.num_particles, 3, 2), "push-forward and unrolled frames are kept"
    monkeypatch.setattr(trainer.optimisation, "pushforward_steps", lambda step: 1)
    recording = Recording(trainer.simulator)
    trainer.optimisation.model = recording
    loss, _ = trainer.optimisation(0)
    assert recording.unrolled_steps == 2
    torch.testing.assert_close(recording.batch.next_position, windows.ahead[:, 0], rtol=0, atol=0)
    torch.testing.assert_close(recording.batch.ahead, windows.ahead[:, 1:], rtol=0, atol=0)
    assert torch.isfinite(loss) and loss > 0
    grads = [p.grad for p in trainer.simulator.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)
    trainer.close()


def test_the_unrolled_loss_averages_every_steps_error(dataset_2d, registry, tmp_path):
    recipe = with_training(tiny_recipe(dataset_2d, registry), unrolled_loss_steps=2)
    trainer = tiny_trainer(recipe, tmp_path, registry)
    optimisation = trainer.optimisation
    windows = optimisation.windows.batch(optimisation.order.draw(0).mine)
    noise = torch.zeros_like(windows.position_sequence)
    mask = trainer.simulator.predicted_mask(windows.particle_type)
    with torch.no_grad():
        prediction, target = trainer.simulator(windows, noise, 2)
    per_step = ((prediction - target) ** 2).sum(-1).reshape(3, -1)[:, mask].mean(1)
    loss = optimisation.gradients(windows, noise, mask)
    torch.testing.assert_close(loss, per_step.double().mean(), rtol=1e-5, atol=0)
    assert per_step[2] != per_step[0], "the steps' errors differ: the mean is not one step's"
    trainer.close()


@pytest.mark.parametrize(
    "other, why",
    [({"capture_step": True}, "not available with capture_step"), ({"partitions": 2}, "not available with partitions")],
)
def test_the_unrolled_loss_is_refused_beside_steps_that_take_one_step_only(dataset_2d, registry, other, why):
    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"].update({"unrolled_loss_steps": 2, **other})
    from gns_framework.config.recipe import validate_recipe

    with pytest.raises(RecipeError, match=rf"training: .*unrolled_loss_steps is {why}"):
        validate_recipe(raw, registry)


def test_rolling_windows_over_per_frame_context_names_each_field_asked():
    from gns_framework.training.parts import rolled_window_problems

    assert rolled_window_problems(2, 3, 0) == []
    problems = rolled_window_problems(0, 3, 4)
    assert [field for field, _ in problems] == ["training.unrolled_loss_steps"]
    assert "step_context" in problems[0][1]
    assert [field for field, _ in rolled_window_problems(1, 1, 4)] == [
        "training.pushforward_steps",
        "training.unrolled_loss_steps",
    ]
