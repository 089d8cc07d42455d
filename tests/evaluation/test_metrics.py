"""Metrics against hand-computed cases, plus invariances of the Sinkhorn distance."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_framework.evaluation.metrics import (
    ParticleRollout,
    RolloutPair,
    kinetic_energy,
    kinetic_energy_error,
    mse_at_horizons,
    mse_per_step,
    pile_profile,
    profile_error,
    rollout_metrics,
    runout_distance,
    sinkhorn_distance,
    summarise,
)
from gns_framework.plugins import load_registry

SAND, WATER, KINEMATIC = 6, 5, 3
UNIT_BOX = [(0.0, 1.0), (0.0, 1.0)]
METRICS = load_registry().metrics()


def rollout_of(position, particle_type, mask=None, start=None) -> ParticleRollout:
    return ParticleRollout.of(position, particle_type, mask, start, kinematic_types={KINEMATIC})


def measure(predicted: ParticleRollout, truth: ParticleRollout, **options):
    """Every installed metric (the built-ins) of ``predicted`` against ``truth``."""
    return rollout_metrics(RolloutPair(predicted, truth, **options), METRICS)


def offset_rollout(steps: int = 7):
    """Two sand particles and one kinematic; particle 0 is predicted k units off in x at step k.

    Per-step MSE (mean over moving particles and the 2 components) is (k^2 / 2 + 0) / 2 = k^2 / 4.
    The kinematic particle is off by 100 and must not count.
    """
    truth = torch.zeros(steps, 3, 2, dtype=torch.float64)
    predicted = truth.clone()
    predicted[:, 0, 0] = torch.arange(1, steps + 1, dtype=torch.float64)
    predicted[:, 2] = 100.0
    particle_type = torch.tensor([SAND, SAND, KINEMATIC])
    return rollout_of(predicted, particle_type), rollout_of(truth, particle_type)


def test_mse_per_step_and_horizons_by_hand():
    predicted, truth = offset_rollout(steps=7)
    per_step = mse_per_step(predicted, truth)
    k = torch.arange(1, 8, dtype=torch.float64)
    torch.testing.assert_close(per_step[0], k**2 / 4)
    horizons = mse_at_horizons(per_step, horizons=(1, 5, 10))
    assert horizons["mse_1"].item() == pytest.approx(0.25)
    assert horizons["mse_5"].item() == pytest.approx((1 + 4 + 9 + 16 + 25) / 5 / 4)
    assert horizons["mse_full"].item() == pytest.approx(140 / 7 / 4)


def test_horizon_beyond_rollout_is_missing_not_clamped():
    predicted, truth = offset_rollout(steps=7)
    horizons = mse_at_horizons(mse_per_step(predicted, truth), horizons=(7, 8, 100))
    assert horizons["mse_7"] is not None
    assert horizons["mse_8"] is None and horizons["mse_100"] is None
    with pytest.raises(ValueError, match="horizons must be >= 1"):
        mse_at_horizons(mse_per_step(predicted, truth), horizons=(0,))


def test_padded_batch_matches_each_rollout_alone():
    predicted, truth = offset_rollout(steps=4)
    # Example 1 has only the first particle; its padding holds garbage that must not count.
    position_p = torch.stack([predicted.position[0], predicted.position[0].clone()])
    position_t = torch.stack([truth.position[0], truth.position[0].clone()])
    position_p[1, :, 1:] = 1e6
    mask = torch.tensor([[True, True, True], [True, False, False]])
    types = truth.particle_type.expand(2, 3)
    per_step = mse_per_step(rollout_of(position_p, types, mask), rollout_of(position_t, types, mask))
    k = torch.arange(1, 5, dtype=torch.float64)
    torch.testing.assert_close(per_step[0], k**2 / 4)
    torch.testing.assert_close(per_step[1], k**2 / 2)


def test_position_mse_refuses_rollouts_of_different_particles():
    _, truth = offset_rollout()
    fewer = rollout_of(truth.position[0, :, :2], truth.particle_type[0, :2])
    with pytest.raises(ValueError, match="same particles"):
        mse_per_step(fewer, truth)


def cloud(n: int = 40, seed: int = 0, dim: int = 2) -> torch.Tensor:
    return torch.rand(n, dim, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def sinkhorn(x: torch.Tensor, y: torch.Tensor, blur: float = 1e-3) -> float:
    ones_x = torch.ones(1, len(x), dtype=torch.bool)
    ones_y = torch.ones(1, len(y), dtype=torch.bool)
    return sinkhorn_distance(x[None], y[None], ones_x, ones_y, blur=blur, diameter=2.0).item()


def test_sinkhorn_of_identical_clouds_is_zero():
    x = cloud()
    assert sinkhorn(x, x) == pytest.approx(0.0, abs=1e-6)


def test_sinkhorn_of_translated_cloud_equals_the_shift_and_grows_with_it():
    x = cloud()
    distances = [sinkhorn(x, x + torch.tensor([shift, 0.0], dtype=torch.float64)) for shift in (0.02, 0.05, 0.1, 0.2)]
    assert distances == pytest.approx([0.02, 0.05, 0.1, 0.2], rel=1e-3)
    assert distances == sorted(distances)


def test_sinkhorn_compares_clouds_of_different_sizes_as_measures():
    x = cloud()
    # Every particle doubled is the same uniform measure.
    assert sinkhorn(x, torch.cat([x, x])) == pytest.approx(0.0, abs=1e-6)


def test_sinkhorn_ignores_masked_particles():
    x, y = cloud(seed=1), cloud(seed=2)
    weight = torch.ones(1, 40, dtype=torch.bool)
    padded_y = torch.cat([y, torch.full((5, 2), 50.0, dtype=torch.float64)])
    padded_weight = torch.cat([weight, torch.zeros(1, 5, dtype=torch.bool)], dim=1)
    masked = sinkhorn_distance(x[None], padded_y[None], weight, padded_weight, blur=1e-3, diameter=2.0).item()
    assert masked == pytest.approx(sinkhorn(x, y), rel=1e-6)


clouds = st.integers(min_value=0, max_value=10_000).map(lambda seed: cloud(n=12, seed=seed))


@settings(max_examples=10, deadline=None)
@given(clouds, clouds, st.randoms(use_true_random=False))
def test_sinkhorn_is_symmetric_and_blind_to_particle_order(x, y, random):
    order = list(range(len(y)))
    random.shuffle(order)
    forward = sinkhorn(x, y)
    assert sinkhorn(y, x) == pytest.approx(forward, rel=1e-3, abs=1e-6)
    assert sinkhorn(x, y[order]) == pytest.approx(forward, rel=1e-6, abs=1e-9)


@settings(max_examples=10, deadline=None)
@given(clouds, clouds, st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
def test_sinkhorn_is_unchanged_by_moving_both_clouds(x, y, dx, dy):
    shift = torch.tensor([dx, dy], dtype=torch.float64)
    ones = torch.ones(1, len(x), dtype=torch.bool)
    near = sinkhorn_distance(x[None], y[None], ones, ones, blur=1e-3, diameter=6.0).item()
    moved = sinkhorn_distance((x + shift)[None], (y + shift)[None], ones, ones, blur=1e-3, diameter=6.0).item()
    assert moved == pytest.approx(near, rel=1e-4, abs=1e-7)


def constant_velocity(step: float, frames: int = 5) -> ParticleRollout:
    """One sand particle moving ``step`` per frame along x, starting at the origin."""
    x = step * torch.arange(1, frames + 1, dtype=torch.float64)
    position = torch.stack([x, torch.zeros_like(x)], dim=-1)[:, None]
    return rollout_of(position, torch.tensor([SAND]), start=torch.zeros(1, 2, dtype=torch.float64))


def test_kinetic_energy_by_hand():
    # 0.01 L per frame at dt = 0.01 s is 1 L/s: energy per unit mass 1/2 in every frame.
    energy = kinetic_energy(constant_velocity(0.01), dt=0.01)
    torch.testing.assert_close(energy, torch.full((1, 5), 0.5, dtype=torch.float64))
    # Without a start frame the first velocity is unknown: one value fewer.
    no_start = rollout_of(constant_velocity(0.01).position[0], torch.tensor([SAND]))
    assert kinetic_energy(no_start, dt=0.01).shape == (1, 4)


def test_kinetic_energy_error_of_exact_rollout_is_zero_and_of_double_speed_is_three_times():
    truth = kinetic_energy(constant_velocity(0.01), dt=0.01)
    error, percent = kinetic_energy_error(truth, truth)
    assert error.item() == 0.0 and percent.item() == 0.0
    error, percent = kinetic_energy_error(kinetic_energy(constant_velocity(0.02), dt=0.01), truth)
    assert error.item() == pytest.approx(1.5)
    assert percent.item() == pytest.approx(300.0)


def collapse(final_front: float) -> ParticleRollout:
    """A sand column on x in [0, 0.2] spreading to [0, final_front]; a kinematic wall at x = 1."""
    column_x = torch.tensor([0.0, 0.1, 0.2, 0.0, 0.1, 0.2], dtype=torch.float64)
    column_y = torch.tensor([0.0, 0.0, 0.0, 0.3, 0.3, 0.3], dtype=torch.float64)
    start = torch.stack([column_x, column_y], dim=-1)
    final = torch.stack([column_x * final_front / 0.2, column_y / 3], dim=-1)
    wall = torch.tensor([[1.0, 0.0], [1.0, 0.5]], dtype=torch.float64)
    position = torch.stack([start, final])
    position = torch.cat([position, wall.expand(2, 2, 2)], dim=1)
    particle_type = torch.tensor([SAND] * 6 + [KINEMATIC] * 2)
    return rollout_of(position, particle_type, start=torch.cat([start, wall]))


def test_runout_of_a_constructed_pile():
    truth, predicted = collapse(0.5), collapse(0.45)
    sand = truth.of_types([SAND])
    assert runout_distance(truth, sand).item() == pytest.approx(0.3)
    assert runout_distance(predicted, sand).item() == pytest.approx(0.25)
    metrics = measure(predicted, truth, dt=0.01, bounds=UNIT_BOX, granular_types={SAND})
    assert metrics["runout_error"].item() == pytest.approx(0.05)
    assert metrics["runout_error_pct"].item() == pytest.approx(100 * 0.05 / 0.3)


def test_final_extent_and_pile_height_errors_of_a_constructed_pile():
    """Extent: front 0.5 against 0.45 of the true 0.5 (10 %); height: the highest sand particle, 0.1 both."""
    truth, predicted = collapse(0.5), collapse(0.45)
    metrics = measure(predicted, truth, dt=0.01, bounds=UNIT_BOX, granular_types={SAND})
    assert metrics["extent_error_pct"].item() == pytest.approx(10.0)
    assert metrics["height_error_pct"].item() == pytest.approx(0.0)
    lower = rollout_of(
        torch.cat([predicted.position[:, :6] * torch.tensor([1.0, 0.8]), predicted.position[:, 6:]], 1),
        predicted.particle_type,
        start=predicted.start,
    )
    metrics = measure(lower, truth, dt=0.01, bounds=[(0.0, 1.0), (-0.1, 1.0)], granular_types={SAND})
    # heights above the floor at -0.1: 0.08 + 0.1 predicted, 0.1 + 0.1 true
    assert metrics["height_error_pct"].item() == pytest.approx(100 * 0.02 / 0.2)
    # The deposit error is the mean of the two: (10 % + 10 %) / 2.
    assert metrics["deposit_error_pct"].item() == pytest.approx(10.0)


def test_pile_profile_and_its_error_by_hand():
    # Four bins of width 0.25 on x; heights above the floor at y = 0.
    position = torch.tensor([[[0.1, 0.2], [0.2, 0.4], [0.6, 0.1], [0.9, 5.0]]], dtype=torch.float64)
    weight = torch.tensor([[True, True, True, False]])
    profile = pile_profile(position, weight, UNIT_BOX, bins=4)
    torch.testing.assert_close(profile[0, [0, 2]], torch.tensor([0.4, 0.1], dtype=torch.float64))
    assert profile[0, 1].isnan() and profile[0, 3].isnan()
    # Predicted pile: bin 0 lower by 0.1, bin 1 holds stray material 0.2 high, bin 2 empty.
    predicted = torch.tensor([[0.3, float("nan"), float("nan"), float("nan")]], dtype=torch.float64)
    predicted[0, 1] = 0.2
    error, percent = profile_error(predicted, profile)
    # Occupied bins 0, 1, 2: errors 0.1, 0.2, 0.1.
    expected = math.sqrt((0.01 + 0.04 + 0.01) / 3)
    assert error.item() == pytest.approx(expected)
    assert percent.item() == pytest.approx(100 * expected / 0.4)


def test_pile_profile_in_3d_bins_both_horizontal_axes():
    position = torch.tensor([[[0.1, 0.1, 0.3], [0.9, 0.1, 0.2], [0.1, 0.9, 0.7]]], dtype=torch.float64)
    profile = pile_profile(position, torch.ones(1, 3, dtype=torch.bool), [(0.0, 1.0)] * 3, bins=2)
    # Cell index is x_bin * 2 + y_bin.
    torch.testing.assert_close(
        profile[0], torch.tensor([0.3, 0.7, 0.2, float("nan")], dtype=torch.float64), equal_nan=True
    )


def test_per_material_breakdown_names_each_material():
    truth = torch.zeros(3, 4, 2, dtype=torch.float64)
    predicted = truth.clone()
    predicted[:, 2:, 1] = 0.2  # only the sand particles are off
    particle_type = torch.tensor([WATER, WATER, SAND, SAND])
    metrics = measure(
        rollout_of(predicted, particle_type),
        rollout_of(truth, particle_type),
        dt=0.01,
        bounds=UNIT_BOX,
        material_names={SAND: "sand", WATER: "water"},
    )
    assert metrics["mse_full[water]"].item() == 0.0
    assert metrics["mse_full[sand]"].item() == pytest.approx(0.04 / 2)
    assert metrics["mse_final[sand]"].item() == pytest.approx(0.02)
    assert metrics["mse_full"].item() == pytest.approx(0.01)


def test_exact_rollout_has_zero_error_everywhere(make_rollout):
    rollout = make_rollout(steps=8)
    truth = rollout_of(
        torch.as_tensor(rollout.ground_truth, dtype=torch.float64),
        torch.as_tensor(rollout.particle_type),
        start=torch.as_tensor(rollout.initial_positions[-1], dtype=torch.float64),
    )
    summary = summarise(measure(truth, truth, dt=0.01, bounds=UNIT_BOX, granular_types={SAND}))
    assert summary["mse_50"] is None and summary["mse_100"] is None
    present = {k: v for k, v in summary.items() if v is not None}
    assert present.pop("sinkhorn_final") == pytest.approx(0.0, abs=1e-6)
    assert present.pop("sinkhorn_final_pct") == pytest.approx(0.0, abs=1e-4)
    assert present.pop("free_deposit") in (0.0, 1.0)  # a property of the true deposit, not an error
    assert all(v == 0.0 for v in present.values()), present


def test_different_particles_drop_position_errors_but_keep_distribution_metrics(make_rollout):
    rollout = make_rollout(steps=5, particles=12)
    truth = rollout_of(
        torch.as_tensor(rollout.ground_truth, dtype=torch.float64), torch.as_tensor(rollout.particle_type)
    )
    coarse = rollout_of(truth.position[0, :, ::2], truth.particle_type[0, ::2])
    metrics = measure(coarse, truth, dt=0.01, bounds=UNIT_BOX, same_particles=False)
    assert metrics["mse_full"] is None and metrics["mse_1"] is None and metrics["mse_per_step"] is None
    assert metrics["sinkhorn_final"].item() > 0
    assert metrics["kinetic_energy_error"] is not None


def test_diverged_prediction_is_inf_from_its_first_bad_frame_not_averaged_away():
    predicted, truth = offset_rollout(steps=4)
    position = torch.cat([truth.position, predicted.position])
    position[1, 2:, 0, 0] = float("nan")
    types = truth.particle_type.expand(2, 3)
    metrics = measure(
        rollout_of(position, types),
        rollout_of(torch.cat([truth.position] * 2), types),
        dt=0.01,
        bounds=UNIT_BOX,
    )
    assert metrics["diverged"].tolist() == [0.0, 1.0]
    assert metrics["mse_per_step"][1, :2].isfinite().all() and metrics["mse_per_step"][1, 2:].isinf().all()
    assert metrics["sinkhorn_final"][1].isinf() and metrics["kinetic_energy_error"][1].isinf()
    summary = summarise(metrics)
    assert summary["diverged"] == 0.5
    assert math.isinf(summary["mse_full"]) and math.isinf(summary["sinkhorn_final"])
    assert summary["mse_1"] == pytest.approx(0.125)


def test_summarise_keeps_missing_values_missing():
    summary = summarise({"a": None, "b": torch.tensor([float("nan")]), "c": torch.tensor([1.0, float("nan"), 3.0])})
    assert summary == {"a": None, "b": None, "c": 2.0}
