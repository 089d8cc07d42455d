"""training/validation.py: the one-step windows, the mean of rollout scores, and keeping the best checkpoint."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from synthetic import soft_sphere_trajectory
from tiny import tiny_recipe, tiny_trainer

from gns_framework.io.checkpoint import load_checkpoint
from gns_framework.io.run_folder import RunFolder
from gns_framework.training.validation import Validation, rollout_score_summary, validation_windows

HISTORY = 3


def _trajectories(count: int, steps: int = 8):
    return [soft_sphere_trajectory(i, frames=steps, block=3, key=f"t{i}") for i in range(count)]


def test_windows_are_spread_evenly_and_batched():
    valid = _trajectories(2)
    batches = validation_windows(valid, HISTORY, count=5, batch_size=2, where="data")
    # 2 trajectories of 8 frames give 2 x 5 windows of 3 inputs and 1 target; 5 of them in batches of 2, 2, 1.
    assert [b.num_examples for b in batches] == [2, 2, 1]


@pytest.mark.parametrize(
    ("valid", "reason"),
    [(None, "no valid split"), ([], "an empty valid split"), ("short", "no valid trajectory longer")],
)
def test_no_usable_valid_split_warns_naming_the_dataset_and_why(valid, reason):
    if valid == "short":
        valid = _trajectories(1, steps=HISTORY)
    with pytest.warns(UserWarning, match=f"data/x: {reason}.*without validation"):
        assert validation_windows(valid, HISTORY, count=4, batch_size=2, where="data/x") == []


def test_rollout_scores_are_averaged_over_the_rollouts_that_have_them():
    scores = iter([{"a": 1.0, "b": 10.0}, {"a": 3.0}, {"a": math.inf, "b": 20.0}])
    summary = rollout_score_summary(None, _trajectories(3), lambda simulator, trajectory: next(scores))
    assert summary["a"] == math.inf, "a diverged rollout makes the mean inf: it can never be the best"
    assert summary["b"] == pytest.approx(15.0), "a scene without the metric is left out, not counted as 0"
    assert summary["a_worst"] == math.inf and summary["b_worst"] == 20.0


def test_the_worst_rollout_is_recorded_beside_the_mean():
    # One scene far off, the others close: the mean hides what the worst shows.
    scores = iter([{"a": 2.0}, {"a": 3.0}, {"a": 40.0}, {"a": 1.0}])
    summary = rollout_score_summary(None, _trajectories(4), lambda simulator, trajectory: next(scores))
    assert summary == {"a": pytest.approx(11.5), "a_worst": 40.0}


def _state(step: int, best: dict) -> dict:
    return {"model": {}, "step": step, "recipe": {}, "scene": {}, "metadata": {}, "plugins": {}, "best": dict(best)}


def _validation(tmp_path, metric="m") -> Validation:
    return Validation([], [], lambda s, t: {}, metric, RunFolder(tmp_path), torch.device("cpu"))


def test_only_a_lower_score_of_the_chosen_metric_is_kept(tmp_path):
    validation = _validation(tmp_path)
    run = RunFolder(tmp_path)
    assert validation.keep_if_best({"m": 5.0}, 3, lambda: _state(3, validation.best)) == run.best_checkpoint
    for worse in ({"m": 6.0}, {"m": 5.0}, {"m": math.inf}, {"m": math.nan}, {"other": 0.0}, {}):
        assert validation.keep_if_best(worse, 9, lambda: _state(9, validation.best)) is None, worse
    record = json.loads(run.best_record.read_text())
    assert record == {"metric": "m", "value": 5.0, "step": 3}
    state = load_checkpoint(run.best_checkpoint)
    assert state["step"] == 3 and state["best"] == record, "the checkpoint records itself as the best"
    assert validation.keep_if_best({"m": 4.0}, 11, lambda: _state(11, validation.best)) is not None
    assert json.loads(run.best_record.read_text())["step"] == 11


def test_a_record_of_another_metric_is_not_restored(tmp_path):
    validation = _validation(tmp_path, metric="m")
    validation.restore_best({"metric": "other", "value": 1.0, "step": 4})
    assert validation.best == {"metric": "m", "value": math.inf, "step": None}
    validation.restore_best({"metric": "m", "value": 2.0, "step": 4})
    assert validation.best == {"metric": "m", "value": 2.0, "step": 4}
    validation.restore_best(None)
    assert validation.best["value"] == 2.0


def test_nothing_to_validate_measures_nothing(tmp_path):
    assert _validation(tmp_path).measure(None) == {}


def test_measure_scores_the_rollouts_and_leaves_the_model_training(dataset_2d, registry, tmp_path):
    trainer = tiny_trainer(tiny_recipe(dataset_2d, registry), tmp_path / "run", registry)
    simulator, valid = trainer.simulator, trainer.data.valid
    batches = validation_windows(valid, simulator.setup.history, count=4, batch_size=2, where="data")
    seen = []

    def score(model, trajectory):
        seen.append(trajectory.key)
        return {"valid_rollout_x": float(len(seen))}

    validation = Validation(batches, valid[:2], score, "valid_rollout_x", RunFolder(tmp_path), torch.device("cpu"))
    simulator.train()
    metrics = validation.measure(simulator)
    assert seen == [t.key for t in valid[:2]] and metrics["valid_rollout_x"] == pytest.approx(1.5)
    assert np.isfinite(metrics["valid_one_step_loss"]) and metrics["valid_one_step_position_mse"] >= 0
    assert simulator.training
    trainer.close()


def test_a_process_that_does_not_report_measures_with_the_others_and_returns_nothing(dataset_2d, registry, tmp_path):
    """A split validation's rank other than 0: it takes part in each one-step measure and rollout, and reports none."""
    trainer = tiny_trainer(tiny_recipe(dataset_2d, registry), tmp_path / "run", registry)
    simulator, valid = trainer.simulator, trainer.data.valid
    batches = validation_windows(valid, simulator.setup.history, count=4, batch_size=2, where="data")
    measured, scored = [], []

    def one_step(model, batch):
        measured.append(batch.num_examples)
        return 1.0, 2.0

    def score(model, trajectory):
        scored.append(trajectory.key)
        return {}

    validation = Validation(
        batches, valid[:2], score, "valid_rollout_x", RunFolder(tmp_path), torch.device("cpu"), one_step, reports=False
    )
    assert validation.measure(simulator) == {}
    assert measured == [2, 2] and scored == [t.key for t in valid[:2]]
    reporting = Validation(batches, [], score, "m", RunFolder(tmp_path), torch.device("cpu"), one_step)
    assert reporting.measure(simulator) == {"valid_one_step_loss": 1.0, "valid_one_step_position_mse": 2.0}
    trainer.close()
