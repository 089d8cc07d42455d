"""Velocity Verlet (leapfrog, kick-drift-kick), second order and symplectic."""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from .semi_implicit_euler import SemiImplicitEuler


class VelocityVerlet(SemiImplicitEuler):
    """``p[t+1] = p[t] + v[t] + a[t]/2``, ``v[t+1] = v[t] + (a[t] + a[t+1])/2``, dt = 1 frame.

    History form: the backward difference ``p[t] - p[t-1]`` is the leapfrog
    half-step velocity ``v[t-1/2]``, and ``v[t] = v[t-1/2] + a[t]/2``. Substituting::

        p[t+1] = p[t] + (p[t] - p[t-1]) + a[t]

    which is the Stoermer-Verlet position recursion: with a position-only history,
    velocity Verlet, leapfrog and semi-implicit Euler make the same position
    sequence. The exact inverse is ``a[t] = p[t+1] - 2 p[t] + p[t-1]``. They differ in
    which velocity they report, and in :meth:`advance` (second order here, first
    order for Euler).

    Stability: symplectic and time-reversible, global error O(dt^2). On the harmonic
    oscillator it is stable for ``omega dt < 2``; the energy oscillates without
    drift between ``1 - (omega dt)^2 / 4`` and 1 times the initial one (started at
    rest). Beyond ``omega dt = 2`` the amplitude grows geometrically.
    """

    name = "velocity_verlet"
    same_position_map_as = "semi_implicit_euler"
    symplectic = True
    stability_bound = 2.0

    @staticmethod
    def advance(
        position: Tensor, velocity: Tensor, acceleration_fn: Callable[[Tensor], Tensor], dt: float
    ) -> tuple[Tensor, Tensor]:
        """One physical step, kick-drift-kick; two force evaluations. Shapes (N, d)."""
        half_kick = velocity + 0.5 * dt * acceleration_fn(position)
        position = position + dt * half_kick
        return position, half_kick + 0.5 * dt * acceleration_fn(position)
