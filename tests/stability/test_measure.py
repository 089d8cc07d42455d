"""Integrators on stiff problems: measured stability limits, bounded and growing energies, near-collisions."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_framework.plugins import load_registry
from gns_framework.stability.measure import (
    collide,
    energy_record,
    explicit_euler_horizon_limit,
    stability_limit,
    stays_bounded,
)
from gns_framework.stability.problems import RepulsiveCollision, SpringChain

pytestmark = [pytest.mark.stability, pytest.mark.usefixtures("one_torch_thread")]

REGISTRY = load_registry()
SYMPLECTIC = ["semi_implicit_euler", "velocity_verlet"]


def advance(name):
    return REGISTRY.get("integrator", name).advance


stiffness = st.floats(0, 6).map(lambda e: 10.0**e)
"""k log-uniform in [1, 1e6]."""
chains = st.builds(SpringChain, num_masses=st.integers(2, 48), stiffness=stiffness)


@pytest.mark.parametrize("name", SYMPLECTIC)
@settings(max_examples=6, deadline=None)
@given(chain=chains)
def test_measured_stability_limit_is_two_over_the_stiffest_frequency(name, chain):
    # k spans 1 to 1e6, so this also checks the k^-1/2 scaling of the limit.
    theory = 2 / chain.highest_frequency
    found = stability_limit(advance(name), chain, 0.5 * theory, 1.5 * theory, steps=1000, rounds=2)
    assert found.dt == pytest.approx(theory, rel=2e-3)
    assert found.unstable_dt > found.dt


@settings(max_examples=15, deadline=None)
@given(chain=chains, omega_dt=st.floats(0.01, 1.95))
def test_symplectic_euler_energy_error_stays_within_its_bound_below_the_limit(chain, omega_dt):
    # From rest, every mode's energy ratio lies in [1/(1 + h/2), 1/(1 - h/2)] for h = omega dt,
    # and the stiffest mode has the largest h.
    record = energy_record(advance("semi_implicit_euler"), chain, omega_dt / chain.highest_frequency, 300)
    ratio = record.relative_error + 1
    assert float(ratio.min()) >= 1 / (1 + omega_dt / 2) * (1 - 1e-9)
    assert float(ratio.max()) <= 1 / (1 - omega_dt / 2) * (1 + 1e-9)


@settings(max_examples=15, deadline=None)
@given(chain=chains, omega_dt=st.floats(0.01, 0.5), steps=st.integers(1, 200))
def test_explicit_euler_energy_grows_every_step_at_most_by_the_stiffest_mode(chain, omega_dt, steps):
    record = energy_record(advance("explicit_euler"), chain, omega_dt / chain.highest_frequency, steps)
    ratio = record.relative_error + 1
    assert bool((ratio[1:] > ratio[:-1]).all()) and float(ratio[0]) > 1
    assert float(ratio[-1]) <= (1 + omega_dt**2) ** steps * (1 + 1e-9)


def test_explicit_euler_has_only_a_horizon_limit():
    chain = SpringChain(32, 1e6)
    bound = explicit_euler_horizon_limit(chain, 1000, 1e8)
    found = stability_limit(advance("explicit_euler"), chain, 1e-3 * bound, 10 * bound, steps=1000, rounds=2)
    # Modes softer than the stiffest grow slower, so the limit (inside the final bracket) is at or above the
    # one-mode bound.
    assert found.unstable_dt >= bound and found.dt < 1.2 * bound
    longer = stays_bounded(advance("explicit_euler"), chain, torch.tensor([found.dt]), steps=4000)
    assert not bool(longer[0])


@pytest.mark.parametrize("name", SYMPLECTIC)
def test_symplectic_schemes_do_not_drift_over_long_runs(name):
    chain = SpringChain(32, 1e6)
    record = energy_record(advance(name), chain, 1.0 / chain.highest_frequency, 5000)
    assert record.finite and record.max_error < 1.0
    assert abs(record.drift) < 1e-3


@pytest.mark.parametrize("name", SYMPLECTIC)
def test_near_collision_conserves_energy_at_a_tenth_of_the_contact_period(name):
    collision = RepulsiveCollision(closest_approach=0.5)
    outcome = collide(advance(name), collision, 0.1 / collision.contact_frequency)
    assert outcome.ok and outcome.energy_error < 1e-6
    assert outcome.closest_approach == pytest.approx(0.5, rel=1e-3)


def test_explicit_euler_gains_energy_in_the_same_collision():
    collision = RepulsiveCollision(closest_approach=0.5)
    outcome = collide(advance("explicit_euler"), collision, 0.1 / collision.contact_frequency)
    assert not outcome.passed_through and outcome.energy_error > 0.1


@pytest.mark.parametrize("name", [*SYMPLECTIC, "explicit_euler"])
def test_too_large_a_step_jumps_through_the_repulsive_wall(name):
    collision = RepulsiveCollision(closest_approach=0.5)
    assert collide(advance(name), collision, 30 / collision.contact_frequency).passed_through
    assert not collide(advance(name), collision, 1 / collision.contact_frequency).passed_through
