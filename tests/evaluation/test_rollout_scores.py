"""evaluation/rollout_scores.py: a validation rollout scored by the installed metrics measured in validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe, tiny_trainer

from gns_framework.evaluation import rollout_scores
from gns_framework.evaluation.candidates import granular_particle_types, learned_positions
from gns_framework.evaluation.report import Prediction, score_prediction
from gns_framework.evaluation.rollout_scores import validation_rollout_scorer


@pytest.fixture(scope="module")
def sand(tmp_path_factory):
    """Soft spheres typed as sand (6): runout, extent and height are measured on them."""
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("sand") / "data", train=2, valid=1, test=0, particle_types=(6,)
    )


@pytest.fixture
def trained(sand, tmp_path, registry):
    trainer = tiny_trainer(tiny_recipe(sand, registry), tmp_path / "run", registry)
    trainer.train(3)
    yield trainer
    trainer.close()


def test_each_tracked_metric_is_the_evaluation_value_of_the_rollout(trained, registry):
    scene, metadata, cpu = trained.data.setup, trained.data.metadata, torch.device("cpu")
    trajectory = trained.data.valid[0]
    scores = validation_rollout_scorer(registry, scene, metadata, cpu)(trained.simulator, trajectory)
    tracked = registry.validation_metrics()
    assert set(scores) == set(tracked), "sand has every built-in validation metric"
    evaluated = score_prediction(
        Prediction(learned_positions(trained.simulator, trajectory, cpu)),
        trajectory,
        scene.history,
        metadata,
        granular_types=granular_particle_types(scene, registry),
        kinematic_types=scene.kinematic_types,
    )
    for name, metric in tracked.items():
        assert scores[name] == pytest.approx(float(evaluated[metric.name].item()), rel=1e-12), name
    deposit = (scores["valid_rollout_extent_error_pct"] + scores["valid_rollout_height_error_pct"]) / 2
    assert scores["valid_rollout_deposit_error_pct"] == pytest.approx(deposit, rel=1e-12)


def test_a_diverged_rollout_scores_inf_everywhere(trained, registry, monkeypatch):
    trajectory = trained.data.valid[0]
    nan = np.full((trajectory.num_steps - trained.simulator.setup.history, *trajectory.position.shape[1:]), np.nan)
    monkeypatch.setattr(rollout_scores, "learned_positions", lambda simulator, case, device: nan)
    score = validation_rollout_scorer(registry, trained.data.setup, trained.data.metadata, torch.device("cpu"))
    values = score(trained.simulator, trajectory)
    assert values and all(math.isinf(v) for v in values.values()), values


def test_metrics_without_granular_particles_are_absent(dataset_2d, tmp_path, registry):
    trainer = tiny_trainer(tiny_recipe(dataset_2d, registry), tmp_path / "run", registry)
    assert granular_particle_types(trainer.data.setup, registry) == []
    score = validation_rollout_scorer(registry, trainer.data.setup, trainer.data.metadata, torch.device("cpu"))
    values = score(trainer.simulator, trainer.data.valid[0])
    assert set(values) == {"valid_rollout_mse", "valid_rollout_sinkhorn_pct"}
    trainer.close()


def test_positions_rolled_elsewhere_are_scored_and_none_scores_nothing(trained, registry):
    """A rollout split over processes hands its positions in (rank 0) or None (the others)."""
    scene, metadata, cpu = trained.data.setup, trained.data.metadata, torch.device("cpu")
    trajectory = trained.data.valid[0]
    rolled = learned_positions(trained.simulator, trajectory, cpu)
    calls = []

    def positions(simulator, case):
        calls.append(case.key)
        return rolled + 1.0 if len(calls) == 1 else None

    score = validation_rollout_scorer(registry, scene, metadata, cpu, positions=positions)
    shifted = score(trained.simulator, trajectory)
    plain = validation_rollout_scorer(registry, scene, metadata, cpu)(trained.simulator, trajectory)
    assert shifted["valid_rollout_mse"] > plain["valid_rollout_mse"], "the positions handed in were scored"
    assert score(trained.simulator, trajectory) == {}
    assert calls == [trajectory.key] * 2
