"""The reference integrator: exact inverses (hypothesis, float64), and its physical form's stability and order."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from oscillator import observed_order, oscillator_energy

from gns_builtins.integrators.semi_implicit_euler import SemiImplicitEuler

finite = st.floats(-10, 10, allow_nan=False, width=64)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 8), st.just(6), st.integers(2, 3)), elements=finite), st.data())
def test_semi_implicit_euler_inverse_round_trip(history, data):
    sequence = torch.from_numpy(history)
    acceleration = torch.from_numpy(data.draw(arrays(np.float64, history[:, 0].shape, elements=finite)))
    integrator = SemiImplicitEuler(SemiImplicitEuler.Params())
    next_position = integrator.next_position(sequence, acceleration)
    torch.testing.assert_close(integrator.target(sequence, next_position), acceleration, rtol=0, atol=1e-9)
    torch.testing.assert_close(
        integrator.next_position(sequence, integrator.target(sequence, next_position)), next_position
    )


@pytest.mark.parametrize("omega_dt", [0.1, 1.0, 1.9])
def test_the_oscillator_energy_stays_within_its_documented_bounds(omega_dt):
    # Started at rest the energy oscillates within a factor 1 / (1 +- omega dt / 2) of the initial one.
    energies = oscillator_energy(SemiImplicitEuler.advance, omega_dt)
    low, high = 1 / (1 + omega_dt / 2), 1 / (1 - omega_dt / 2)
    assert low * (1 - 1e-6) <= min(energies) and max(energies) <= high * (1 + 1e-6)


def test_semi_implicit_euler_blows_up_beyond_omega_dt_2():
    assert oscillator_energy(SemiImplicitEuler.advance, 2.1, steps=200)[-1] > 1e6


def test_order_of_accuracy_of_the_physical_form():
    assert observed_order(SemiImplicitEuler.advance) == pytest.approx(1, abs=0.1)
