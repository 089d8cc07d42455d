"""Explicit Euler: its position map, the lagged acceleration it predicts, and its unstable physical form."""

from __future__ import annotations

import itertools

import pytest
import torch
from oscillator import frames_of_force_law, observed_order, oscillator_energy

from gns_builtins.integrators.explicit_euler import ExplicitEuler

EULER = ExplicitEuler(ExplicitEuler.Params())


def test_next_position_adds_the_last_displacement_and_the_prediction():
    # p[t-1] = (0.1, 0.3), p[t] = (0.25, 0.5): v = (0.15, 0.2); plus a = (0.4, -0.2) gives (0.55, 0); p = (0.8, 0.5).
    history = torch.tensor([[[9.0, 9.0], [0.1, 0.3], [0.25, 0.5]]], dtype=torch.float64)
    prediction = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    expected = torch.tensor([[0.8, 0.5]], dtype=torch.float64)
    # Only the last two frames count: the first (9, 9) must not move the result.
    torch.testing.assert_close(EULER.next_position(history, prediction), expected, rtol=0, atol=1e-15)
    torch.testing.assert_close(EULER.target(history, expected), prediction, rtol=0, atol=1e-15)


def test_the_window_ending_at_frame_t_predicts_the_acceleration_of_frame_t_minus_1():
    # The documented history form: p[t+1] - 2 p[t] + p[t-1] = a(p[t-1]) when the frames come from advance, dt = 1.
    frames, matrix = frames_of_force_law(ExplicitEuler.advance)
    for t in range(1, frames.shape[0] - 1):
        window = frames[t - 1 : t + 1].transpose(0, 1)
        lagged = frames[t - 1] @ matrix.T
        # Values of order 1 combined by a few float64 operations: a few ulps.
        torch.testing.assert_close(EULER.target(window, frames[t + 1]), lagged, rtol=0, atol=1e-14)
        assert not torch.allclose(lagged, frames[t] @ matrix.T), "the frames differ enough to tell t from t - 1"


def test_advance_moves_with_the_old_velocity_and_accelerates_from_the_old_position():
    # x = 1, v = 0.2, a(x) = -x, dt = 0.5: x' = 1 + 0.5 * 0.2 = 1.1 and v' = 0.2 - 0.5 * 1 = -0.3.
    x, v = ExplicitEuler.advance(torch.tensor([1.0]), torch.tensor([0.2]), lambda p: -p, 0.5)
    assert (float(x), float(v)) == pytest.approx((1.1, -0.3), rel=1e-6)


def test_explicit_euler_grows_the_oscillator_energy_geometrically():
    omega_dt = 0.1
    energies = oscillator_energy(ExplicitEuler.advance, omega_dt, steps=100)
    # Each step multiplies the amplitude by sqrt(1 + (omega dt)^2), the energy by 1 + (omega dt)^2.
    assert energies[-1] == pytest.approx((1 + omega_dt**2) ** 100, rel=1e-9)


def test_explicit_euler_is_declared_unstable_for_every_step():
    # stability_bound 0: even a small step gains energy at every step (the growth factor above is > 1 for any dt).
    assert ExplicitEuler.stability_bound == 0.0 and not ExplicitEuler.symplectic
    energies = oscillator_energy(ExplicitEuler.advance, 0.01, steps=50)
    assert all(b > a for a, b in itertools.pairwise(energies))


def test_order_of_accuracy_of_the_physical_form():
    assert observed_order(ExplicitEuler.advance) == pytest.approx(1, abs=0.1)
