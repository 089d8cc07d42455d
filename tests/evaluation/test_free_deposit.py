"""Free deposits: a deposit reaching both side walls is the box's; one stopping short of either is the flow's."""

from __future__ import annotations

import math

import numpy as np
import torch

from gns_builtins.metrics import BUILTIN_METRICS
from gns_framework.evaluation.free_deposit import free_deposits, wall_gaps
from gns_framework.evaluation.metrics import ParticleRollout, RolloutPair

H = 0.01
"""Particle spacing of the lattices below, m."""
BOUNDS = [[0.0, 1.0], [0.0, 0.5]]


def lattice(x_low: float, x_high: float, layers: int = 3) -> torch.Tensor:
    """(N, 2) a layer of sand on the floor from ``x_low`` to ``x_high``, ``H`` apart, float64."""
    xs = torch.arange(x_low, x_high + H / 2, H, dtype=torch.float64)
    ys = torch.arange(layers, dtype=torch.float64) * H + H / 2
    return torch.cartesian_prod(xs, ys)


def test_wall_gaps_are_the_distances_from_each_wall_to_the_nearest_sand():
    sand = lattice(0.1, 0.7)[None]
    weight = torch.ones(sand.shape[:2], dtype=torch.bool)
    torch.testing.assert_close(wall_gaps(sand, weight, BOUNDS), torch.tensor([[0.1, 0.3]], dtype=torch.float64))
    # Particles outside the weight (an obstacle at the right wall) are not the deposit's.
    weight[0, -3:] = False
    torch.testing.assert_close(wall_gaps(sand, weight, BOUNDS), torch.tensor([[0.1, 0.3 + H]], dtype=torch.float64))


def spread(start: torch.Tensor, x_low: float, x_high: float) -> torch.Tensor:
    """The particles of ``start`` laid out in a thin layer from ``x_low`` to ``x_high`` (same particles)."""
    final = start.clone()
    final[:, 0] = torch.linspace(x_low, x_high, len(start), dtype=torch.float64)
    final[:, 1] = H / 2
    return final


def test_a_deposit_is_free_unless_it_ends_within_a_spacing_of_both_walls():
    start = lattice(0.0, 0.2, layers=10)
    final = torch.stack(
        [
            spread(start, H / 2, 1.0 - H / 2),  # wall to wall: the box sets its extent
            spread(start, 0.9 * H, 1.0 - 0.9 * H),  # still within a spacing of each
            spread(start, H / 2, 0.8),  # short of the right wall: free
            spread(start, 1.5 * H, 1.0 - H / 2),  # a spacing and a half from the left wall: free
        ]
    )
    weight = torch.ones(final.shape[:2], dtype=torch.bool)
    # The spacing is the start's (the lattice's H), not that of the spread-out deposit (under H / 4 here).
    assert free_deposits(final, start.expand_as(final), weight, BOUNDS).tolist() == [False, False, True, True]
    # Padding is no sand: a padded particle at the far wall does not make a deposit reach it.
    padded = torch.cat([final[2:3], torch.tensor([[[1.0, H]]], dtype=torch.float64)], dim=1)
    padded_start = torch.cat([start[None], torch.tensor([[[1.0, H]]], dtype=torch.float64)], dim=1)
    mask = torch.cat([weight[2:3], torch.zeros(1, 1, dtype=torch.bool)], dim=1)
    assert free_deposits(padded, padded_start, mask, BOUNDS).tolist() == [True]


def test_the_builtin_metric_reads_the_true_deposit_only():
    start = lattice(0.0, 0.2, layers=10)
    n = len(start)
    true_final = spread(start, H / 2, 1.0 - H / 2)  # spans the box
    short = true_final.clone()
    short[:, 0] *= 0.5  # the prediction stops half-way: free, were it the truth
    types = torch.full((n,), 6)

    def rollout(final):
        return ParticleRollout.of(torch.stack([start, final]), types, start=start, kinematic_types=())

    metric = next(m for m in BUILTIN_METRICS if m.name == "free_deposit")
    pair = RolloutPair(rollout(short), rollout(true_final), dt=0.01, bounds=BOUNDS, granular_types=(6,))
    assert metric.function(pair).tolist() == [0.0]
    swapped = RolloutPair(rollout(true_final), rollout(short), dt=0.01, bounds=BOUNDS, granular_types=(6,))
    assert metric.function(swapped).tolist() == [1.0]
    assert metric.function(RolloutPair(rollout(short), rollout(true_final), dt=0.01, bounds=BOUNDS)) is None
    assert math.isclose(float(wall_gaps(short[None], torch.ones(1, n, dtype=torch.bool), BOUNDS)[0, 1]), 0.5 + H / 4)


def test_a_case_in_a_box_of_its_own_is_measured_against_its_walls_not_the_datasets():
    from types import SimpleNamespace

    from gns_framework.data.trajectory import Trajectory
    from gns_framework.evaluation.report import Prediction, score_prediction

    start = lattice(0.0, 0.2, layers=10)
    final = spread(start, H / 2, 1.0 - H / 2)  # wall to wall in its own 1 m box
    frames = np.stack([start, start, final, final]).astype(np.float32)
    types = np.full(len(start), 6)
    metadata = SimpleNamespace(dt=0.01, bounds=[[0.0, 2.0], [0.0, 1.0]])  # the dataset's boxes reach 2 m

    def scores(bounds):
        case = Trajectory(frames, types, None, key="case", bounds=bounds)
        values = score_prediction(Prediction(frames[2:]), case, 2, metadata, granular_types=(6,), kinematic_types=())
        return float(values["free_deposit"])

    own = np.array(BOUNDS, dtype=np.float32)
    assert scores(own) == 0.0, "it reaches both of its own walls"
    assert scores(None) == 1.0, "in the dataset's 2 m box it would stop half-way"
