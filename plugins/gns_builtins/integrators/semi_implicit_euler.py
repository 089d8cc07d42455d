"""The reference update: semi-implicit (symplectic) Euler with dt = 1 frame."""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from gns_framework.contracts import Integrator


class SemiImplicitEuler(Integrator):
    """``v[t+1] = v[t] + a``, ``p[t+1] = p[t] + v[t+1]`` with ``v[t] = p[t] - p[t-1]``.

    In positions this is ``p[t+1] = 2 p[t] - p[t-1] + a`` (Stoermer-Verlet). Its inverse
    is exact: ``a = (p[t+1] - p[t]) - (p[t] - p[t-1])``.

    Stability: symplectic, first order. On the harmonic oscillator ``a = -omega^2 x``
    it is stable for ``omega dt < 2``: the energy oscillates without drift, within
    a factor ``1 / (1 +- omega dt / 2)`` of the initial one (started at rest), an
    error of order ``omega dt``. Beyond ``omega dt = 2`` the amplitude grows geometrically.
    """

    name = "semi_implicit_euler"
    predicts = "acceleration"
    symplectic = True
    stability_bound = 2.0

    def next_position(self, position_sequence: Tensor, prediction: Tensor) -> Tensor:
        most_recent_position = position_sequence[:, -1]
        most_recent_velocity = most_recent_position - position_sequence[:, -2]
        new_velocity = most_recent_velocity + prediction
        return most_recent_position + new_velocity

    def target(self, position_sequence: Tensor, next_position: Tensor) -> Tensor:
        previous_velocity = position_sequence[:, -1] - position_sequence[:, -2]
        next_velocity = next_position - position_sequence[:, -1]
        return next_velocity - previous_velocity

    @staticmethod
    def advance(
        position: Tensor, velocity: Tensor, acceleration_fn: Callable[[Tensor], Tensor], dt: float
    ) -> tuple[Tensor, Tensor]:
        """One physical step: ``v' = v + dt a(x)``, then ``x' = x + dt v'``. Shapes (N, d)."""
        velocity = velocity + dt * acceleration_fn(position)
        return position + dt * velocity, velocity
