"""Integrators: exact inverses, the history forms they document, and their stability."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gns_framework.plugins import load_registry

REGISTRY = load_registry()
NAMES = REGISTRY.names("integrator")
SECOND_ORDER = ["semi_implicit_euler", "explicit_euler", "velocity_verlet"]


def make(name):
    cls = REGISTRY.get("integrator", name)
    return cls(cls.Params())


finite = st.floats(-10, 10, allow_nan=False, width=64)


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(NAMES),
    arrays("float64", (5, 6, 3), elements=finite),
    arrays("float64", (5, 3), elements=finite),
)
def test_target_is_the_exact_inverse_of_next_position(name, sequence, prediction):
    integrator = make(name)
    sequence, prediction = torch.from_numpy(sequence), torch.from_numpy(prediction)
    recovered = integrator.target(sequence, integrator.next_position(sequence, prediction))
    assert torch.allclose(recovered, prediction, atol=1e-11, rtol=1e-12)


def test_constant_acceleration_is_reproduced_exactly():
    # p(t) = a t^2 / 2: every second-order scheme's history form must predict a.
    t = torch.arange(7, dtype=torch.float64)[None, :, None]
    a = torch.tensor([[0.3, -1.2]], dtype=torch.float64)
    trajectory = 0.5 * a[:, None] * t**2
    for name in SECOND_ORDER:
        integrator = make(name)
        assert torch.allclose(integrator.target(trajectory[:, :6], trajectory[:, 6]), a), name
    velocity = make("velocity_euler").target(trajectory[:, :6], trajectory[:, 6])
    assert torch.allclose(velocity, trajectory[:, 6] - trajectory[:, 5])


def test_velocity_euler_is_normalised_with_velocity_statistics():
    assert REGISTRY.get("integrator", "velocity_euler").predicts == "velocity"
    assert all(REGISTRY.get("integrator", n).predicts == "acceleration" for n in SECOND_ORDER)


def oscillator_energy(name, omega_dt, steps=2000):
    """Energy after ``steps`` of x'' = -omega^2 x (omega = 1) from x = 1, v = 0, relative to the start."""
    advance = REGISTRY.get("integrator", name).advance
    x, v = torch.tensor([1.0], dtype=torch.float64), torch.tensor([0.0], dtype=torch.float64)
    energies = []
    for _ in range(steps):
        x, v = advance(x, v, lambda p: -p, omega_dt)
        energies.append(float(0.5 * v**2 + 0.5 * x**2) / 0.5)
    return energies


ENERGY_BOUNDS = {
    "semi_implicit_euler": lambda h: (1 / (1 + h / 2), 1 / (1 - h / 2)),
    "velocity_verlet": lambda h: (1 - h * h / 4, 1.0),
}


@pytest.mark.parametrize("name", sorted(ENERGY_BOUNDS))
@pytest.mark.parametrize("omega_dt", [0.1, 1.0, 1.9])
def test_symplectic_schemes_keep_the_oscillator_energy_within_their_documented_bounds(name, omega_dt):
    energies = oscillator_energy(name, omega_dt)
    low, high = ENERGY_BOUNDS[name](omega_dt)
    assert low * (1 - 1e-6) <= min(energies) and max(energies) <= high * (1 + 1e-6)


@pytest.mark.parametrize("name", ["semi_implicit_euler", "velocity_verlet"])
def test_symplectic_schemes_blow_up_beyond_omega_dt_2(name):
    assert oscillator_energy(name, 2.1, steps=200)[-1] > 1e6


def test_explicit_euler_grows_the_oscillator_energy_geometrically():
    omega_dt = 0.1
    energies = oscillator_energy("explicit_euler", omega_dt, steps=100)
    # Each step multiplies the amplitude by sqrt(1 + (omega dt)^2), the energy by 1 + (omega dt)^2.
    assert energies[-1] == pytest.approx((1 + omega_dt**2) ** 100, rel=1e-9)


@pytest.mark.parametrize("name, order", [("velocity_verlet", 2), ("semi_implicit_euler", 1), ("explicit_euler", 1)])
def test_order_of_accuracy_of_the_physical_form(name, order):
    def position_error(dt):
        advance = REGISTRY.get("integrator", name).advance
        x, v = torch.tensor([1.0], dtype=torch.float64), torch.tensor([0.0], dtype=torch.float64)
        for _ in range(round(1.0 / dt)):
            x, v = advance(x, v, lambda p: -p, dt)
        return abs(float(x) - math.cos(1.0))

    assert math.log2(position_error(0.02) / position_error(0.01)) == pytest.approx(order, abs=0.1)


SHARING = [n for n in NAMES if REGISTRY.get("integrator", n).same_position_map_as]


def test_the_duplicates_are_declared():
    assert sorted(SHARING) == ["explicit_euler", "velocity_verlet"]


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(SHARING) if SHARING else st.nothing(),
    arrays("float64", (5, 3, 2), elements=finite),
    arrays("float64", (5, 2), elements=finite),
)
def test_an_integrator_that_says_it_shares_a_position_map_does(name, history, prediction):
    # The fact on the component is what training refuses it by: it must be true.
    mine, theirs = make(name), make(REGISTRY.get("integrator", name).same_position_map_as)
    history, prediction = torch.from_numpy(history), torch.from_numpy(prediction)
    torch.testing.assert_close(
        mine.next_position(history, prediction),
        theirs.next_position(history, prediction),
        rtol=0,
        atol=1e-12 * (1 + float(history.abs().max() + prediction.abs().max())),
    )
    following = theirs.next_position(history, prediction)
    torch.testing.assert_close(
        mine.target(history, following),
        theirs.target(history, following),
        rtol=0,
        atol=1e-11 * (1 + float(history.abs().max() + prediction.abs().max())),
    )


def test_every_other_acceleration_integrator_has_a_position_map_of_its_own():
    # A new integrator that duplicates semi-implicit Euler without saying so would train the same model.
    history = torch.tensor([[[0.0, 0.0], [0.1, 0.3], [0.25, 0.5]]], dtype=torch.float64)
    prediction = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    reference = make("semi_implicit_euler").next_position(history, prediction)
    for name in NAMES:
        if name in SHARING or name == "semi_implicit_euler":
            continue
        assert not torch.allclose(make(name).next_position(history, prediction), reference), name
