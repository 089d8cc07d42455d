"""Which particles are kinematic is the materials' word everywhere: a third-party kinematic material
with an id other than the public datasets' 3 is left out of the statistics and of every error metric."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.contracts import Material
from gns_framework.data.metadata import DatasetMetadata, compute_statistics
from gns_framework.data.rollout import Rollout
from gns_framework.data.trajectory import Trajectory
from gns_framework.evaluation.report import score_rollout
from gns_framework.hookspecs import hookimpl
from gns_framework.plugins import load_registry

SAND, BALLAST = 6, 11


class Ballast(Material):
    """Track ballast moved by a prescribed path: kinematic, with an id the public datasets never use."""

    name = "ballast"
    particle_type = BALLAST
    kinematic = True


class BallastPlugin:
    @staticmethod
    @hookimpl
    def gns_materials():
        return [Ballast]


@pytest.fixture(scope="module")
def registry():
    return load_registry(plugins=[("ballast", BallastPlugin)])


def sand_and_ballast(frames: int = 14) -> np.ndarray:
    """(T, 4, 2): two sand particles falling under gravity, two ballast particles shaken hard."""
    t = np.arange(frames, dtype=np.float64)[:, None]
    sand = np.stack([np.hstack([0.3 + 0 * t, 0.8 - 2e-4 * t**2]), np.hstack([0.4 + 1e-3 * t, 0.7 - 2e-4 * t**2])], 1)
    ballast = 0.5 + 0.2 * np.sin(np.stack([np.hstack([3 * t, t]), np.hstack([t, 5 * t])], 1))
    return np.concatenate([sand, ballast], axis=1).astype(np.float32)


def test_statistics_leave_out_a_kinematic_material_of_any_id(registry):
    position = sand_and_ballast()
    both = Trajectory(position, np.array([SAND, SAND, BALLAST, BALLAST]))
    sand_only = Trajectory(position[:, :2], np.array([SAND, SAND]))
    statistics = compute_statistics([both], registry.kinematic_types())
    expected = compute_statistics([sand_only], ())
    for key, values in expected.items():
        assert statistics[key] == pytest.approx(values, rel=1e-12, abs=1e-15), key
    # With only the public datasets' id 3 kinematic, the shaken ballast would count.
    assert compute_statistics([both], (3,))["vel_std"] != pytest.approx(expected["vel_std"])


def test_metrics_leave_out_a_kinematic_material_of_any_id(registry):
    position = sand_and_ballast()
    history = 6
    predicted = position[history:].copy()
    predicted[:, 2:] += 0.05  # only the prescribed ballast is off: it must not count
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0), (0.0, 1.0)],
        sequence_length=len(position),
        default_connectivity_radius=0.1,
        dim=2,
        dt=0.01,
        vel_mean=[0.0, 0.0],
        vel_std=[1.0, 1.0],
        acc_mean=[0.0, 0.0],
        acc_std=[1.0, 1.0],
    )
    rollout = Rollout(Trajectory(position, np.array([SAND, SAND, BALLAST, BALLAST])), predicted, history, metadata)
    summary = score_rollout(rollout, kinematic_types=registry.kinematic_types(), metrics=registry.metrics())
    assert summary["mse_full"] == 0.0 and summary["mse_final"] == 0.0
    assert summary["sinkhorn_final"] == pytest.approx(0.0, abs=1e-6)
    assert summary["kinetic_energy_error"] == 0.0
    assert score_rollout(rollout, kinematic_types=(3,), metrics=registry.metrics())["mse_full"] > 0
