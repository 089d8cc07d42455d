"""Recipe options for short, effective training: schedules, data-relative noise, frame stride, rollout validation."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
import torch
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe_mapping

from gns_framework.assembly.data import open_dataset
from gns_framework.assembly.trained import load_trained
from gns_framework.config.recipe import OptimizerSpec, validate_recipe
from gns_framework.data.metadata import compute_statistics
from gns_framework.errors import RecipeError
from gns_framework.io.checkpoint import load_checkpoint
from gns_framework.model.noise import training_noise_std
from gns_framework.model.rollout import rollout
from gns_framework.training.optim import learning_rate, make_optimizer
from gns_framework.training.trainer import Trainer


@pytest.fixture(scope="module")
def sand_dataset(tmp_path_factory):
    """Soft spheres typed as sand (6), so validation rollouts also measure runout."""
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("sand") / "data", train=3, valid=2, test=1, particle_types=(6,)
    )


def _problems(raw, registry) -> str:
    with pytest.raises(RecipeError) as caught:
        validate_recipe(raw, registry)
    return str(caught.value)


# --- learning-rate schedules -------------------------------------------------------------------


def test_exponential_schedule_is_the_reference_formula():
    spec = OptimizerSpec(lr_init=1e-4, lr_min=1e-6, lr_decay=0.1, lr_decay_steps=5e6)
    for step in (0, 1, 1000, 5_000_000):
        expected = 1e-6 + (1e-4 - 1e-6) * 0.1 ** (step / 5e6)
        assert learning_rate(spec, step, total_steps=10) == pytest.approx(expected, rel=1e-12)


def test_cosine_schedule_warms_up_then_reaches_the_floor_at_the_last_step():
    spec = OptimizerSpec(schedule="cosine", lr_init=1e-3, lr_min=1e-5, warmup_steps=10)
    rates = [learning_rate(spec, step, total_steps=110) for step in range(111)]
    assert rates[0] == pytest.approx(1e-4) and rates[9] == pytest.approx(1e-3)
    assert all(a < b for a, b in itertools.pairwise(rates[:10]))
    assert rates[10] == pytest.approx(1e-3)
    assert all(a >= b for a, b in itertools.pairwise(rates[10:]))
    assert rates[60] == pytest.approx(1e-5 + (1e-3 - 1e-5) / 2)
    assert rates[110] == pytest.approx(1e-5)


def test_the_optimizer_follows_the_schedule():
    spec = OptimizerSpec(schedule="cosine", lr_init=1e-2, lr_min=0.0, warmup_steps=2)
    parameter = torch.nn.Parameter(torch.zeros(1))
    optimizer, scheduler = make_optimizer([parameter], spec, total_steps=6)
    seen = []
    for _ in range(6):
        seen.append(optimizer.param_groups[0]["lr"])
        parameter.grad = torch.ones(1)
        optimizer.step()
        scheduler.step()
    assert seen == pytest.approx([learning_rate(spec, s, 6) for s in range(6)])


@pytest.mark.parametrize(
    "optimizer, location",
    [
        ({"schedule": "linear"}, "training.optimizer.schedule"),
        ({"warmup_steps": -1}, "training.optimizer.warmup_steps"),
        ({"lr_init": 1e-4, "lr_min": 1e-3}, "training.optimizer"),
    ],
)
def test_bad_schedules_are_refused_with_their_location(optimizer, location, dataset_2d, registry):
    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"]["optimizer"] = optimizer
    assert location in _problems(raw, registry)


# --- noise relative to the data ------------------------------------------------------------------


def test_relative_noise_is_a_fraction_of_the_mean_velocity_std(dataset_2d, registry):
    recipe = validate_recipe(tiny_recipe_mapping(dataset_2d, noise_relative=0.25), registry)
    metadata = open_dataset(recipe.dataset, registry).metadata()
    assert training_noise_std(recipe.model, metadata) == pytest.approx(0.25 * np.mean(metadata.vel_std))
    absolute = validate_recipe(tiny_recipe_mapping(dataset_2d, noise_std=3e-4), registry)
    assert training_noise_std(absolute.model, metadata) == 3e-4


def test_relative_noise_reaches_training_and_the_normalisation(dataset_2d, registry, tmp_path):
    recipe = validate_recipe(tiny_recipe_mapping(dataset_2d, tmp_path, noise_relative=0.5), registry)
    trainer = Trainer(recipe, registry, progress=False)
    expected = 0.5 * float(np.mean(trainer.data.metadata.vel_std))
    assert trainer.noise_std == pytest.approx(expected)
    std = trainer.simulator.features.velocity_stats.std
    combined = torch.sqrt(torch.tensor(trainer.data.metadata.vel_std, dtype=torch.float32) ** 2 + expected**2)
    torch.testing.assert_close(std, combined)
    trainer.close()


def test_a_resolved_recipe_with_relative_noise_validates_again(dataset_2d, registry):
    """Checkpoints store the resolved recipe, with noise_std at its default beside noise_relative."""
    recipe = validate_recipe(tiny_recipe_mapping(dataset_2d, noise_relative=0.1), registry)
    again = validate_recipe(recipe.resolved(), registry)
    assert again.model.noise_relative == 0.1 and again.resolved() == recipe.resolved()


@pytest.mark.parametrize(
    "model, message",
    [
        ({"noise_relative": -0.1}, "model.noise_relative"),
        ({"noise_relative": 0.1, "noise_std": 1e-4}, "not both"),
    ],
)
def test_bad_noise_settings_are_refused(model, message, dataset_2d, registry):
    assert message in _problems(tiny_recipe_mapping(dataset_2d, **model), registry)


# --- frame stride -------------------------------------------------------------------------------


def test_frame_stride_keeps_every_kth_frame_and_recomputes_statistics(dataset_2d, registry):
    raw = tiny_recipe_mapping(dataset_2d)
    plain = open_dataset(validate_recipe(raw, registry).dataset, registry)
    raw["dataset"]["frame_stride"] = 3
    strided = open_dataset(validate_recipe(raw, registry).dataset, registry)
    stored, seen = plain.metadata(), strided.metadata()
    assert seen.dt == pytest.approx(3 * stored.dt)
    assert seen.sequence_length == math.ceil(stored.sequence_length / 3)
    assert seen.frame_stride == 3
    full, thinned = plain.split("valid")[1], strided.split("valid")[1]
    np.testing.assert_array_equal(thinned.position, full.position[::3])
    np.testing.assert_array_equal(thinned.particle_type, full.particle_type)
    expected = compute_statistics(
        [strided.split("train")[i] for i in range(len(strided.split("train")))], registry.kinematic_types()
    )
    assert seen.vel_std == pytest.approx(expected["vel_std"]) and seen.acc_std == pytest.approx(expected["acc_std"])
    # A step over 3 frames: velocities about 3x those between stored frames.
    assert 2 < np.mean(seen.vel_std) / np.mean(stored.vel_std) < 4


def test_a_strided_model_rolls_out_on_strided_frames(dataset_2d, registry, tmp_path):
    raw = tiny_recipe_mapping(dataset_2d, tmp_path)
    raw["dataset"]["frame_stride"] = 2
    raw["training"].update(steps=2, checkpoint_every=2)
    trainer = Trainer(validate_recipe(raw, registry), registry, progress=False)
    trainer.train()
    trainer.close()
    loaded = load_trained(tmp_path / "checkpoints" / "checkpoint-000000002.pt", registry)
    assert loaded.recipe.dataset.frame_stride == 2 and loaded.metadata.dt == pytest.approx(trainer.data.metadata.dt)
    test = open_dataset(loaded.recipe.dataset, registry).split("test")[0]
    frames = open_dataset(validate_recipe(tiny_recipe_mapping(dataset_2d), registry).dataset, registry).split("test")[0]
    result = rollout(loaded.simulator, test)
    assert result.predicted.shape[0] == math.ceil(frames.num_steps / 2) - loaded.simulator.setup.history


def test_bad_frame_stride_is_refused(dataset_2d, registry):
    raw = tiny_recipe_mapping(dataset_2d)
    raw["dataset"]["frame_stride"] = 0
    assert "dataset.frame_stride" in _problems(raw, registry)


# --- validation by rollout and the best checkpoint -------------------------------------------------


def _rollout_validated(sand_dataset, tmp_path, registry, **training):
    raw = tiny_recipe_mapping(sand_dataset, tmp_path)
    raw["training"].update(steps=4, validate_every=2, checkpoint_every=4, validation_rollouts=2, **training)
    return Trainer(validate_recipe(raw, registry), registry, progress=False)


def test_validation_rolls_out_and_keeps_the_best_checkpoint(sand_dataset, tmp_path, registry):
    trainer = _rollout_validated(sand_dataset, tmp_path, registry)
    trainer.train()
    trainer.close()
    logged = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    validations = [m for m in logged if "valid_rollout_mse" in m]
    assert [m["step"] for m in validations] == [2, 4]
    for m in validations:
        assert m["valid_rollout_mse"] > 0 and m["valid_rollout_sinkhorn_pct"] >= 0
        assert "valid_rollout_runout_error_pct" in m
        # The deposit error is each rollout's mean of extent and height errors, averaged: with both
        # measured on every rollout, the mean of the two averages.
        parts = (m["valid_rollout_extent_error_pct"], m["valid_rollout_height_error_pct"])
        assert m["valid_rollout_deposit_error_pct"] == pytest.approx(sum(parts) / 2, rel=1e-9)
        # The worst rollout is recorded beside the mean, and is never below it.
        assert m["valid_rollout_deposit_error_pct_worst"] >= m["valid_rollout_deposit_error_pct"]
    best = json.loads((tmp_path / "checkpoints" / "best.json").read_text())
    scores = {m["step"]: m["valid_rollout_mse"] for m in validations}
    assert best["metric"] == "valid_rollout_mse" and best["step"] == min(scores, key=scores.get)
    assert best["value"] == pytest.approx(scores[best["step"]])
    state = load_checkpoint(tmp_path / "checkpoints" / "best.pt")
    assert state["step"] == best["step"] and state["best"] == best


def test_a_worse_score_never_replaces_the_best(sand_dataset, tmp_path, registry):
    trainer = _rollout_validated(sand_dataset, tmp_path, registry, best_metric="valid_rollout_sinkhorn_pct")
    assert trainer.keep_if_best({"valid_rollout_sinkhorn_pct": 5.0}) is not None
    trainer.step = 7
    assert trainer.keep_if_best({"valid_rollout_sinkhorn_pct": 6.0}) is None
    assert trainer.keep_if_best({"valid_rollout_sinkhorn_pct": math.inf}) is None
    assert trainer.keep_if_best({"valid_rollout_mse": 0.0}) is None
    assert json.loads((tmp_path / "checkpoints" / "best.json").read_text())["value"] == 5.0
    trainer.close()


def test_resume_restores_the_best_score(sand_dataset, tmp_path, registry):
    trainer = _rollout_validated(sand_dataset, tmp_path, registry)
    trainer.train()
    trainer.close()
    best = json.loads((tmp_path / "checkpoints" / "best.json").read_text())
    resumed = _rollout_validated(sand_dataset, tmp_path, registry)
    resumed.checkpoints.resume()
    assert resumed.best == best
    resumed.close()


def test_bad_rollout_validation_settings_are_refused(dataset_2d, registry):
    raw = tiny_recipe_mapping(dataset_2d)
    raw["training"].update(validation_rollouts=-1, best_metric="valid_one_step_loss")
    problems = _problems(raw, registry)
    assert "training.validation_rollouts" in problems and "training.best_metric" in problems
