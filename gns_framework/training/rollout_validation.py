"""Validation by rollout: what a trained simulator is for, measured while it trains.

The one-step loss says how well the model predicts one frame from ground-truth
inputs; a rollout feeds it its own predictions for the whole trajectory, so it
measures what users see (drift, clumping, a collapse that does not run out). The
one-step loss and rollout error often disagree late in training, which is why the
best checkpoint is chosen by a rollout metric.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

import numpy as np
import torch

from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..evaluation.candidates import learned_positions
from ..evaluation.report import Prediction, score_prediction
from ..model.learned_simulator import LearnedSimulator
from ..plugins import load_registry

METRICS = {
    "valid_rollout_mse": "mse_full",
    "valid_rollout_sinkhorn_pct": "sinkhorn_final_pct",
    "valid_rollout_runout_error_pct": "runout_error_pct",
    "valid_rollout_extent_error_pct": "extent_error_pct",
    "valid_rollout_height_error_pct": "height_error_pct",
}
"""Tracked name -> :func:`rollout_metrics` key, each averaged over the validation rollouts."""

DEPOSIT = "valid_rollout_deposit_error_pct"
"""Mean over the validation rollouts of the mean of each one's final extent and height errors, %:
the shape of the deposit a geotechnical user reads off, scene by scene. A final-cloud
Sinkhorn error averaged over scenes is dominated by boxes full of sand that hardly move,
and can be small while single columns stop too early or slide too far."""


def validation_rollout_metrics(
    simulator: LearnedSimulator,
    trajectories: Sequence[Trajectory],
    metadata: DatasetMetadata,
    granular_types: Collection[int],
    device: torch.device,
) -> dict[str, float]:
    """Mean rollout errors of ``simulator`` over ``trajectories`` (full length, from their first C frames).

    Scored as ``gns evaluate`` scores a learned model: a diverged rollout scores
    ``inf`` in every metric, so it can never be the best. Runout, extent, height and
    the deposit error (:data:`DEPOSIT`) are reported only where the scene has granular particles.
    """
    totals: dict[str, list[float]] = {name: [] for name in (*METRICS, DEPOSIT)}
    measured = [m for m in load_registry().metrics() if m.name in METRICS.values()]
    for trajectory in trajectories:
        prediction = Prediction(learned_positions(simulator, trajectory, device))
        metrics = score_prediction(
            prediction, trajectory, simulator.scene.history, metadata, granular_types=granular_types,
            kinematic_types=simulator.scene.kinematic_types, metrics=measured,
        )
        found = {}
        for name, key in METRICS.items():
            value = metrics.get(key)
            if value is not None:
                found[name] = float(value.item())
                totals[name].append(found[name])
        shape = [found.get(f"valid_rollout_{part}_error_pct") for part in ("extent", "height")]
        if None not in shape:
            totals[DEPOSIT].append(float(np.mean(shape)))
    return {name: float(np.mean(values)) for name, values in totals.items() if values}
