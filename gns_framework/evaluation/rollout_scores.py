"""The scorer of training's validation rollouts, from the installed metrics measured in validation."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from ..contracts import ModelSetup
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..model.learned_simulator import LearnedSimulator
from ..plugins import Registry
from .candidates import granular_particle_types, learned_positions
from .report import Prediction, score_prediction


def validation_rollout_scorer(
    registry: Registry,
    scene: ModelSetup,
    metadata: DatasetMetadata,
    device: torch.device,
    positions: Callable[[LearnedSimulator, Trajectory], np.ndarray | None] | None = None,
) -> Callable[[LearnedSimulator, Trajectory], dict[str, float]]:
    """``score(simulator, trajectory)``: ``{valid_rollout_<validation>: error}`` of one full rollout.

    Each installed metric with a ``validation`` name is measured as ``gns evaluate``
    measures it, on the rollout from the trajectory's first C frames: a diverged
    rollout scores ``inf`` in every metric, so it can never be the best. A metric
    that cannot be taken on the scene (runout without granular particles) is absent.

    ``positions(simulator, trajectory)`` rolls out the (S, N, d) predicted positions (NaN where
    it diverged); default: one process's rollout on ``device``. Where it returns None (a process
    that takes part in a rollout split over several but does not hold the result), the score is empty.
    """
    tracked = registry.validation_metrics()
    metrics = list(tracked.values())
    granular = granular_particle_types(scene, registry)

    def one_process(simulator: LearnedSimulator, trajectory: Trajectory) -> np.ndarray:
        return learned_positions(simulator, trajectory, device)

    rolled = positions if positions is not None else one_process

    def score(simulator: LearnedSimulator, trajectory: Trajectory) -> dict[str, float]:
        predicted = rolled(simulator, trajectory)
        if predicted is None:
            return {}
        prediction = Prediction(predicted)
        values = score_prediction(
            prediction,
            trajectory,
            simulator.setup.history,
            metadata,
            granular_types=granular,
            kinematic_types=simulator.setup.kinematic_types,
            metrics=metrics,
        )
        found = {name: values.get(metric.name) for name, metric in tracked.items()}
        return {name: float(value.item()) for name, value in found.items() if value is not None}

    return score
