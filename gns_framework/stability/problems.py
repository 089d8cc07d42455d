"""Stiff test problems with known answers, for integrators' physical ``advance``.

Each problem gives ``acceleration(position)`` and ``energy(position, velocity)`` on
float64 tensors with any leading batch dimensions, so one run can try many time
steps at once (``dt`` of shape (B, 1, 1) against states of shape (B, N, d)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class SpringChain:
    """N equal masses in a line joined by N - 1 equal linear springs, free ends.

    The state is the displacement of each mass from rest (rest lengths drop out of
    a linear chain). The normal-mode frequencies are
    ``omega_j = 2 sqrt(k/m) sin(pi j / (2N))``, j = 0..N-1, so a scheme stable for
    ``omega dt < 2`` on the oscillator is stable on the chain for
    ``dt < 2 / omega_{N-1}``: the stiffest mode sets the limit.

    Attributes:
        num_masses: N >= 2.
        stiffness: k, force per unit extension (N/m in SI).
        mass: m of each particle (kg).

    Shapes: displacement and velocity (..., N, 1).
    """

    num_masses: int
    stiffness: float
    mass: float = 1.0

    @property
    def highest_frequency(self) -> float:
        """omega_{N-1}, rad per unit time."""
        n = self.num_masses
        return 2.0 * math.sqrt(self.stiffness / self.mass) * math.sin(math.pi * (n - 1) / (2 * n))

    def acceleration(self, displacement: Tensor) -> Tensor:
        extension = displacement[..., 1:, :] - displacement[..., :-1, :]
        force = torch.zeros_like(displacement)
        force[..., :-1, :] += self.stiffness * extension
        force[..., 1:, :] -= self.stiffness * extension
        return force / self.mass

    def energy(self, displacement: Tensor, velocity: Tensor) -> Tensor:
        """Kinetic plus spring energy, shape (...)."""
        extension = displacement[..., 1:, :] - displacement[..., :-1, :]
        kinetic = 0.5 * self.mass * (velocity**2).sum((-2, -1))
        return kinetic + 0.5 * self.stiffness * (extension**2).sum((-2, -1))

    def initial_state(self, seed: int = 0) -> tuple[Tensor, Tensor]:
        """At rest, displaced in a zigzag (mostly the stiffest mode) plus 10% noise (every mode)."""
        generator = torch.Generator().manual_seed(seed)
        zigzag = torch.tensor([(-1.0) ** i for i in range(self.num_masses)], dtype=torch.float64)
        noise = 0.1 * torch.randn(self.num_masses, generator=generator, dtype=torch.float64)
        displacement = (zigzag + noise)[:, None]
        return displacement, torch.zeros_like(displacement)


@dataclass(frozen=True)
class RepulsiveCollision:
    """Two equal masses meeting head-on in 1D under ``U(r) = epsilon (sigma / r)^12``.

    The purely repulsive r^-12 wall stiffens without bound as the particles close:
    at the closest approach ``r_min`` the local frequency is
    ``omega = sqrt(U''(r_min) / mu)`` with reduced mass ``mu = m / 2``. The speed is
    chosen so the particles turn at ``r_min = closest_approach * sigma``; an exact
    integrator would send them apart with the energy they came with.

    Attributes:
        closest_approach: r_min / sigma (< 1: a near-collision, deep into the wall).
        start_separation: r at t = 0, in units of sigma (U there, 1.5^-12 = 0.8% of
            epsilon, is small against the barrier ``closest_approach^-12``).
        sigma, epsilon, mass: length, energy and mass scales.

    Shapes: position and velocity (..., 2, 1); particle 0 starts on the left.
    """

    closest_approach: float
    start_separation: float = 1.5
    sigma: float = 1.0
    epsilon: float = 1.0
    mass: float = 1.0

    @property
    def reduced_mass(self) -> float:
        return self.mass / 2

    @property
    def approach_speed(self) -> float:
        """Relative speed at the start that turns the particles at ``r_min``."""
        barrier = self.epsilon * self.closest_approach**-12 - self.epsilon * (self.sigma / self.start_separation) ** 12
        return math.sqrt(2 * barrier / self.reduced_mass)

    @property
    def contact_frequency(self) -> float:
        """omega at the closest approach, rad per unit time."""
        r_min = self.closest_approach * self.sigma
        curvature = 156 * self.epsilon * self.sigma**12 / r_min**14
        return math.sqrt(curvature / self.reduced_mass)

    @property
    def bounce_time(self) -> float:
        """Time to close from ``start_separation`` and separate again, overestimated by the free flight."""
        return 2 * self.start_separation * self.sigma / self.approach_speed

    def separation(self, position: Tensor) -> Tensor:
        """r = x_1 - x_0, shape (...)."""
        return position[..., 1, 0] - position[..., 0, 0]

    def acceleration(self, position: Tensor) -> Tensor:
        r = self.separation(position)[..., None, None]
        push = (12 * self.epsilon * self.sigma**12 / self.mass) / r**13
        # Equal and opposite: particle 0 is pushed left, particle 1 right.
        return push * position.new_tensor([[-1.0], [1.0]])

    def energy(self, position: Tensor, velocity: Tensor) -> Tensor:
        """Kinetic plus repulsive energy, shape (...)."""
        kinetic = 0.5 * self.mass * (velocity**2).sum((-2, -1))
        return kinetic + self.epsilon * (self.sigma / self.separation(position)) ** 12

    def initial_state(self) -> tuple[Tensor, Tensor]:
        half = 0.5 * self.start_separation * self.sigma
        speed = 0.5 * self.approach_speed
        position = torch.tensor([[-half], [half]], dtype=torch.float64)
        velocity = torch.tensor([[speed], [-speed]], dtype=torch.float64)
        return position, velocity
