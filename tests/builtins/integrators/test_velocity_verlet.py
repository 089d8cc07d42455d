"""Velocity Verlet: its history form, its kick-drift-kick step, and its stability on the oscillator."""

from __future__ import annotations

import pytest
import torch
from oscillator import frames_of_force_law, observed_order, oscillator_energy

from gns_builtins.integrators.velocity_verlet import VelocityVerlet

VERLET = VelocityVerlet(VelocityVerlet.Params())


def test_next_position_is_the_stoermer_verlet_recursion():
    # p[t+1] = 2 p[t] - p[t-1] + a: 2 (0.25, 0.5) - (0.1, 0.3) + (0.4, -0.2) = (0.8, 0.5).
    history = torch.tensor([[[9.0, 9.0], [0.1, 0.3], [0.25, 0.5]]], dtype=torch.float64)
    prediction = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    expected = torch.tensor([[0.8, 0.5]], dtype=torch.float64)
    torch.testing.assert_close(VERLET.next_position(history, prediction), expected, rtol=0, atol=1e-15)
    torch.testing.assert_close(VERLET.target(history, expected), prediction, rtol=0, atol=1e-15)


def test_the_window_ending_at_frame_t_predicts_the_acceleration_of_frame_t():
    # The documented history form: frames made by advance (dt = 1) satisfy p[t+1] - 2 p[t] + p[t-1] = a(p[t]).
    frames, matrix = frames_of_force_law(VelocityVerlet.advance)
    for t in range(1, frames.shape[0] - 1):
        window = frames[t - 1 : t + 1].transpose(0, 1)
        current = frames[t] @ matrix.T
        # Values of order 1 combined by a few float64 operations: a few ulps.
        torch.testing.assert_close(VERLET.target(window, frames[t + 1]), current, rtol=0, atol=1e-14)
        assert not torch.allclose(current, frames[t - 1] @ matrix.T), "the frames differ enough to tell t from t - 1"


def test_advance_is_kick_drift_kick():
    # x = 1, v = 0, a(x) = -x, dt = 0.5: half kick v = -0.25, drift x = 0.875, kick v = -0.25 - 0.25 * 0.875.
    x, v = VelocityVerlet.advance(torch.tensor([1.0]), torch.tensor([0.0]), lambda p: -p, 0.5)
    assert (float(x), float(v)) == pytest.approx((0.875, -0.46875), rel=1e-6)


@pytest.mark.parametrize("omega_dt", [0.1, 1.0, 1.9])
def test_the_oscillator_energy_stays_within_its_documented_bounds(omega_dt):
    # Started at rest the energy oscillates between 1 - (omega dt)^2 / 4 and 1 times the initial one.
    energies = oscillator_energy(VelocityVerlet.advance, omega_dt)
    low, high = 1 - omega_dt * omega_dt / 4, 1.0
    assert low * (1 - 1e-6) <= min(energies) and max(energies) <= high * (1 + 1e-6)


def test_velocity_verlet_blows_up_beyond_omega_dt_2():
    assert oscillator_energy(VelocityVerlet.advance, 2.1, steps=200)[-1] > 1e6


def test_the_declared_stability_bound_is_where_the_oscillator_turns_unstable():
    bound = VelocityVerlet.stability_bound
    assert VelocityVerlet.symplectic and bound == 2.0
    assert max(oscillator_energy(VelocityVerlet.advance, 0.99 * bound, steps=500)) <= 1 + 1e-6
    assert oscillator_energy(VelocityVerlet.advance, 1.01 * bound, steps=500)[-1] > 1e3


def test_order_of_accuracy_of_the_physical_form():
    assert observed_order(VelocityVerlet.advance) == pytest.approx(2, abs=0.1)
