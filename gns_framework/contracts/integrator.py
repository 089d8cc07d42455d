"""The integrator contract: the prediction to the next position, and back."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, Literal

from torch import Tensor

from .params import ComponentParams, Params


class Integrator(ABC):
    """Turns the model's (de-normalised) prediction into the next position, and back.

    Time is in frames (dt = 1): velocities and accelerations are finite
    differences of positions, as in the reference model. ``predicts`` says which
    statistics normalise the decoder's output.

    Integrators that model a second-order ODE may also offer the physical form
    ``advance(position, velocity, acceleration_fn, dt) -> (position, velocity)``
    (one step of ``dx/dt = v, dv/dt = acceleration_fn(x)``), for use with a force
    law instead of a learned model (stability studies, ground-truth generation).
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    predicts: ClassVar[Literal["acceleration", "velocity"]] = "acceleration"
    same_position_map_as: ClassVar[str | None] = None
    """The integrator whose position map this one shares, when its scheme differs only in
    ``advance``. With a history of positions alone, explicit Euler and velocity Verlet move
    a particle by ``p[t+1] = 2 p[t] - p[t-1] + a`` exactly as semi-implicit Euler does: a
    learned model trains the same with either, so training refuses the duplicate and names
    this one, while ``gns stability`` still studies its ``advance`` under force laws."""
    symplectic: ClassVar[bool] = False
    """Whether ``advance`` is symplectic: below its stability bound the energy stays bounded, with no drift."""
    stability_bound: ClassVar[float | None] = None
    """Largest ``omega dt`` for which ``advance`` is stable on the harmonic oscillator
    ``a = -omega^2 x`` (2 for symplectic Euler and velocity Verlet); 0 when no step is
    stable (explicit Euler); None without a physical form. ``gns stability`` checks it."""

    def __init__(self, params: ComponentParams):
        self.params = params

    @abstractmethod
    def next_position(self, position_sequence: Tensor, prediction: Tensor) -> Tensor:
        """(N, C, d) history and (N, d) prediction -> (N, d) next position."""

    @abstractmethod
    def target(self, position_sequence: Tensor, next_position: Tensor) -> Tensor:
        """Exact inverse of :meth:`next_position`: the prediction that reaches ``next_position``."""
