"""The stiff test problems with known answers (``gns_framework.stability.problems``): each acceleration is the
force of its energy, the spring chain's stiffest frequency is that of its linear dynamics, and the collision turns
at the closest approach it is built for, with the contact frequency of its potential there. All in float64, where
these identities hold to ~1e-12 relative."""

from __future__ import annotations

import math

import pytest
import torch

from gns_framework.stability.problems import RepulsiveCollision, SpringChain

pytestmark = pytest.mark.stability


def test_chain_frequency_matches_the_linearised_dynamics():
    chain = SpringChain(8, 250.0)
    laplacian = torch.stack([chain.acceleration(torch.eye(8, dtype=torch.float64)[i][:, None])[:, 0] for i in range(8)])
    assert math.sqrt(float(torch.linalg.eigvalsh(-laplacian).max())) == pytest.approx(
        chain.highest_frequency, rel=1e-12
    )


def test_two_masses_oscillate_at_the_textbook_frequency():
    # One spring between two masses: the relative coordinate has reduced mass m/2, so omega = sqrt(2k/m).
    assert SpringChain(2, stiffness=50.0, mass=0.5).highest_frequency == pytest.approx(math.sqrt(200.0), rel=1e-12)


@pytest.mark.parametrize(
    "problem, state",
    [
        (SpringChain(5, stiffness=30.0, mass=2.0), SpringChain(5, 30.0).initial_state(seed=3)[0]),
        (RepulsiveCollision(closest_approach=0.6, mass=3.0), RepulsiveCollision(0.6).initial_state()[0] * 0.7),
    ],
    ids=["spring chain", "collision"],
)
def test_the_acceleration_is_the_force_of_the_potential_energy_over_the_mass(problem, state):
    position = state.clone().requires_grad_(True)
    potential = problem.energy(position, torch.zeros_like(position))  # at rest: the energy is all potential
    (gradient,) = torch.autograd.grad(potential, position)
    expected = -gradient / problem.mass
    torch.testing.assert_close(problem.acceleration(state), expected, rtol=1e-12, atol=1e-12 * expected.abs().max())


def test_the_chain_starts_at_rest_mostly_in_its_stiffest_mode():
    chain = SpringChain(6, 1e4)
    displacement, velocity = chain.initial_state(seed=1)
    assert displacement.shape == velocity.shape == (6, 1) and displacement.dtype == torch.float64
    assert torch.count_nonzero(velocity) == 0
    # A zigzag of amplitude 1 with 10 % noise: the signs alternate.
    signs = torch.sign(displacement[:, 0]).tolist()
    assert signs == [1.0, -1.0, 1.0, -1.0, 1.0, -1.0]
    assert torch.equal(chain.initial_state(seed=1)[0], displacement)  # reproducible
    assert not torch.equal(chain.initial_state(seed=2)[0], displacement)


def test_the_collision_energy_is_the_barrier_at_its_closest_approach():
    collision = RepulsiveCollision(closest_approach=0.5, start_separation=1.5, epsilon=2.0, sigma=1.0, mass=1.0)
    position, velocity = collision.initial_state()
    assert collision.separation(position).item() == pytest.approx(1.5, rel=1e-15)
    assert velocity[:, 0].tolist() == [collision.approach_speed / 2, -collision.approach_speed / 2]  # head-on
    # Where the particles turn all the energy is potential: E = epsilon (sigma / r_min)^12 = 2 * 2^12.
    assert collision.energy(position, velocity).item() == pytest.approx(2.0 * 0.5**-12, rel=1e-12)


def test_the_contact_frequency_is_the_curvature_of_the_potential_over_the_reduced_mass():
    collision = RepulsiveCollision(closest_approach=0.7, epsilon=1.5, sigma=2.0, mass=4.0)
    r = torch.tensor(0.7 * 2.0, dtype=torch.float64, requires_grad=True)
    potential = collision.epsilon * (collision.sigma / r) ** 12
    (slope,) = torch.autograd.grad(potential, r, create_graph=True)
    (curvature,) = torch.autograd.grad(slope, r)
    assert collision.contact_frequency == pytest.approx(math.sqrt(curvature.item() / 2.0), rel=1e-12)
