"""Measurements of an integrator's physical ``advance`` on the stiff problems.

``advance(position, velocity, acceleration_fn, dt) -> (position, velocity)`` is the
physical form of the built-in integrators (see :class:`~gns_framework.contracts.Integrator`).
Energies are compared relative to the initial one, ``E / E0 - 1``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from .problems import RepulsiveCollision, SpringChain

Advance = Callable[[Tensor, Tensor, Callable[[Tensor], Tensor], "float | Tensor"], tuple[Tensor, Tensor]]


@dataclass(frozen=True)
class EnergyRecord:
    """Relative energy error ``E / E0 - 1`` after each step of one run, shape (steps,)."""

    relative_error: Tensor

    @property
    def finite(self) -> bool:
        return bool(torch.isfinite(self.relative_error).all())

    @property
    def first_non_finite_step(self) -> int | None:
        bad = (~torch.isfinite(self.relative_error)).nonzero()
        return int(bad[0, 0]) + 1 if len(bad) else None

    @property
    def max_error(self) -> float:
        """max |E / E0 - 1| over the run (inf once it diverged)."""
        return float(torch.nan_to_num(self.relative_error.abs(), nan=math.inf).max())

    @property
    def drift(self) -> float:
        """Secular drift: mean relative error over the last tenth of the run minus over the first tenth.

        A bounded oscillation (symplectic schemes) averages out; growth does not.
        """
        tenth = max(1, len(self.relative_error) // 10)
        return float(self.relative_error[-tenth:].mean() - self.relative_error[:tenth].mean())


def energy_record(advance: Advance, chain: SpringChain, dt: float, steps: int, seed: int = 0) -> EnergyRecord:
    """Run the chain from its initial state for ``steps`` steps of ``dt`` and record the energy error."""
    position, velocity = chain.initial_state(seed)
    initial = chain.energy(position, velocity)
    errors = torch.empty(steps, dtype=torch.float64)
    for step in range(steps):
        position, velocity = advance(position, velocity, chain.acceleration, dt)
        errors[step] = chain.energy(position, velocity) / initial - 1
    return EnergyRecord(errors)


def stays_bounded(
    advance: Advance, chain: SpringChain, dt: Tensor, steps: int, growth: float = 1e8, seed: int = 0
) -> Tensor:
    """(B,) bool: whether the energy stays below ``growth`` times the initial one for ``steps`` steps of each dt.

    All B time steps run at once (the state is batched as (B, N, 1)).
    """
    position, velocity = chain.initial_state(seed)
    position = position.expand(len(dt), -1, -1).clone()
    velocity = velocity.expand(len(dt), -1, -1).clone()
    initial = chain.energy(position, velocity)
    step_size = dt.to(torch.float64)[:, None, None]
    worst = torch.ones(len(dt), dtype=torch.float64)
    for _ in range(steps):
        position, velocity = advance(position, velocity, chain.acceleration, step_size)
        ratio = torch.nan_to_num(chain.energy(position, velocity) / initial, nan=math.inf)
        worst = torch.maximum(worst, ratio)
    return worst <= growth


@dataclass(frozen=True)
class StabilityLimit:
    """The largest time step found stable, and the bracket ``(stable, unstable)`` it was narrowed to."""

    dt: float
    unstable_dt: float

    def relative_to(self, reference: float) -> float:
        return self.dt / reference


def stability_limit(
    advance: Advance,
    chain: SpringChain,
    low: float,
    high: float,
    steps: int = 4000,
    growth: float = 1e8,
    candidates: int = 31,
    rounds: int = 4,
) -> StabilityLimit:
    """Largest dt in ``[low, high]`` whose energy stays below ``growth`` x initial for ``steps`` steps.

    Bisection generalised to ``candidates`` interior points per round (all run at once
    as a batch): each round keeps the sub-interval between the last stable candidate
    and the first unstable one, so the bracket shrinks by ``candidates + 1`` per round
    (31 candidates, 4 rounds: a relative precision of about 1e-6 of ``high - low``).

    Raises ValueError when ``low`` is unstable or ``high`` is stable.
    """
    ends = stays_bounded(advance, chain, torch.tensor([low, high], dtype=torch.float64), steps, growth)
    if not ends[0] or ends[1]:
        raise ValueError(f"the bracket [{low:g}, {high:g}] must start stable and end unstable (got {ends.tolist()})")
    for _ in range(rounds):
        trial = torch.linspace(low, high, candidates + 2, dtype=torch.float64)[1:-1]
        stable = stays_bounded(advance, chain, trial, steps, growth)
        unstable = (~stable).nonzero()
        first_unstable = int(unstable[0, 0]) if len(unstable) else candidates
        if first_unstable > 0:
            low = float(trial[first_unstable - 1])
        if first_unstable < candidates:
            high = float(trial[first_unstable])
    return StabilityLimit(low, high)


def explicit_euler_horizon_limit(chain: SpringChain, steps: int, growth: float) -> float:
    """dt at which the stiffest mode alone would grow its energy ``growth``-fold in ``steps`` explicit Euler steps.

    Explicit Euler multiplies each mode's energy by ``1 + (omega dt)^2`` per step, so it
    has no stability limit, only a horizon-dependent one: ``sqrt(growth^(1/n) - 1) / omega``.
    """
    return math.sqrt(growth ** (1 / steps) - 1) / chain.highest_frequency


@dataclass(frozen=True)
class CollisionOutcome:
    """One head-on collision: the energy error once the particles are apart again, and whether they tunnelled."""

    dt: float
    steps: int
    energy_error: float
    passed_through: bool
    closest_approach: float

    @property
    def ok(self) -> bool:
        return not self.passed_through and math.isfinite(self.energy_error)


def collide(advance: Advance, collision: RepulsiveCollision, dt: float) -> CollisionOutcome:
    """Run the collision for its bounce time; relative energy error at the end (|E / E0 - 1|)."""
    position, velocity = collision.initial_state()
    initial = collision.energy(position, velocity)
    steps = math.ceil(collision.bounce_time / dt)
    closest = collision.separation(position)
    for _ in range(steps):
        position, velocity = advance(position, velocity, collision.acceleration, dt)
        closest = torch.fmin(closest, collision.separation(position))
    # A step that jumps over the r^-12 wall leaves r < 0 (or NaN at r = 0): the particles passed through.
    passed_through = not bool(closest > 0)
    error = math.inf if passed_through else abs(float(collision.energy(position, velocity) / initial) - 1)
    return CollisionOutcome(dt, steps, error, passed_through, float(closest) / collision.sigma)


def collision_dt_limit(
    advance: Advance, collision: RepulsiveCollision, tolerance: float = 0.01, iterations: int = 10
) -> float:
    """Largest dt, bisected in log space, whose collision ends with an energy error below ``tolerance``.

    The bracket is ``[1e-3, 10] / omega_contact`` (10 iterations: within 4%); the
    result is in the problem's time unit, and is the bracket's low end when no dt in
    it meets the tolerance. The error need not be monotonic in dt, so this is the
    threshold bisection finds, not a guarantee for every smaller dt.
    """
    scale = 1 / collision.contact_frequency
    low, high = math.log(1e-3 * scale), math.log(10 * scale)
    for _ in range(iterations):
        middle = 0.5 * (low + high)
        if collide(advance, collision, math.exp(middle)).energy_error < tolerance:
            low = middle
        else:
            high = middle
    return math.exp(low)
