"""Explicit (forward) Euler: position first with the old velocity, then velocity."""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from .semi_implicit_euler import SemiImplicitEuler


class ExplicitEuler(SemiImplicitEuler):
    """``p[t+1] = p[t] + v[t]``, ``v[t+1] = v[t] + a[t]`` with dt = 1 frame.

    History form: a position step uses the velocity *before* the current
    acceleration acts, so ``p[t] - p[t-1] = v[t-1]`` and ``v[t] = v[t-1] + a[t-1]``.
    The acceleration that moves the particle from ``p[t]`` to ``p[t+1]`` is the one of
    the previous frame::

        p[t+1] = 2 p[t] - p[t-1] + a[t-1]

    so the prediction made from the window ending at frame t is ``a[t-1]``, and the
    exact inverse is ``a[t-1] = (p[t+1] - p[t]) - (p[t] - p[t-1])``. The position map
    equals :class:`SemiImplicitEuler`'s; only what the prediction means (the lagged
    acceleration) differs, so a learned model trains the same with either. The
    schemes differ in :meth:`advance`, where the acceleration comes from a force law.

    Stability: not symplectic. On the harmonic oscillator ``a = -omega^2 x`` every
    step multiplies the amplitude by ``sqrt(1 + (omega dt)^2)``: unstable for every
    ``omega dt > 0``, energy grows geometrically. Use it only as a baseline.
    """

    name = "explicit_euler"
    same_position_map_as = "semi_implicit_euler"
    symplectic = False
    stability_bound = 0.0

    @staticmethod
    def advance(
        position: Tensor, velocity: Tensor, acceleration_fn: Callable[[Tensor], Tensor], dt: float
    ) -> tuple[Tensor, Tensor]:
        """One physical step: ``x' = x + dt v``, ``v' = v + dt a(x)`` (both from the old state)."""
        return position + dt * velocity, velocity + dt * acceleration_fn(position)
