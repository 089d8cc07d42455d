"""Constitutive models the MLS-MPM simulator supports, with their parameters (SI units).

A material picks a model by name (``Material.constitutive_model``) and may
override defaults (``Material.physical_parameters``); a scene may override
them again per block, or per particle through recorded material properties.
Each model turns its parameters into the per-particle arrays the kernels read
and states its elastic wave speed, which bounds the stable substep.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class ConstitutiveModel(BaseModel, ABC):
    """Parameters of one model; unknown names are errors."""

    model_config = ConfigDict(extra="forbid")

    name: ClassVar[str]
    kernel_id: ClassVar[int]
    density: float = Field(gt=0, description="kg/m^3")

    @abstractmethod
    def wave_speed(self) -> float:
        """Fastest elastic wave, m/s: the CFL limit is dx / wave_speed."""

    @staticmethod
    @abstractmethod
    def kernel_parameters(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Per-particle ``mu``, ``lam``, ``param_a``, ``param_b`` arrays (see the P2G kernel)."""

    def viscous_substep_limit(self, dx: float, dim: int) -> float:
        """Largest stable substep of explicit viscous diffusion, s; unlimited for a model without viscosity."""
        return math.inf


_Values = TypeVar("_Values", np.ndarray, np.float64)
"""Per-particle arrays, or one value."""


def _lame(youngs: _Values, poisson: _Values) -> tuple[_Values, _Values]:
    mu = youngs / (2 * (1 + poisson))
    lam = youngs * poisson / ((1 + poisson) * (1 - 2 * poisson))
    return mu, lam


class _Elastic(ConstitutiveModel):
    youngs_modulus: float = Field(gt=0, description="Pa")
    poisson_ratio: float = Field(ge=0, lt=0.5)

    def wave_speed(self) -> float:
        mu, lam = _lame(np.float64(self.youngs_modulus), np.float64(self.poisson_ratio))
        return float(math.sqrt((lam + 2 * mu) / self.density))


class DruckerPragerSand(_Elastic):
    """Sand: Hencky elasticity with Drucker-Prager plasticity, no cohesion (Klar et al. 2016).

    ``friction`` is the Coulomb friction coefficient tan(phi); the
    cone slope is alpha = sqrt(2/3) * 2 sin(phi) / (3 - sin(phi)).
    """

    name: ClassVar[str] = "drucker_prager"
    kernel_id: ClassVar[int] = 0
    density: float = Field(default=2200.0, gt=0)
    youngs_modulus: float = Field(default=3.537e5, gt=0)
    poisson_ratio: float = Field(default=0.3, ge=0, lt=0.5)
    friction: float = Field(default=math.tan(math.radians(30)), gt=0, lt=10)

    @staticmethod
    def kernel_parameters(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        mu, lam = _lame(values["youngs_modulus"], values["poisson_ratio"])
        sin_phi = np.sin(np.arctan(values["friction"]))
        alpha = math.sqrt(2 / 3) * 2 * sin_phi / (3 - sin_phi)
        return {"mu": mu, "lam": lam, "param_a": alpha, "param_b": np.zeros_like(mu)}


class WeaklyCompressibleFluid(ConstitutiveModel):
    """Water: pressure from the Tait equation p = K / gamma (J^-gamma - 1), clipped at 0, and a
    Newtonian viscous stress 2 eta dev(D) (D the symmetric velocity gradient, eta the dynamic viscosity).

    K sets the speed of sound sqrt(K / rho); keep it about 10x the fastest flow
    so density varies by ~1 %. Real water has eta = 1e-3 Pa s, which at
    laboratory scale barely slows a dam break; the default 0 keeps the
    inviscid model.
    """

    name: ClassVar[str] = "weakly_compressible"
    kernel_id: ClassVar[int] = 1
    density: float = Field(default=1000.0, gt=0)
    bulk_modulus: float = Field(default=2.0e5, gt=0, description="Pa")
    eos_exponent: float = Field(default=7.0, ge=1, description="Tait gamma")
    viscosity: float = Field(default=0.0, ge=0, description="dynamic viscosity eta, Pa s (water: 1e-3)")

    def wave_speed(self) -> float:
        # The Tait stiffness grows as J^-(gamma+1) under compression; allow 10 % compression.
        return math.sqrt(self.bulk_modulus * 0.9 ** -(self.eos_exponent + 1) / self.density)

    def viscous_substep_limit(self, dx: float, dim: int) -> float:
        # Explicit diffusion of momentum, kinematic viscosity eta / rho: nu dt / dx^2 <= 1 / (2 d).
        if self.viscosity == 0:
            return math.inf
        return self.density * dx**2 / (2 * dim * self.viscosity)

    @staticmethod
    def kernel_parameters(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        zeros = np.zeros_like(values["bulk_modulus"])
        return {
            "mu": values["viscosity"],
            "lam": zeros,
            "param_a": values["bulk_modulus"],
            "param_b": values["eos_exponent"],
        }


def _von_mises_arrays(youngs: np.ndarray, poisson: np.ndarray, yield_stress: np.ndarray) -> dict[str, np.ndarray]:
    """The von Mises return map's kernel inputs for a uniaxial yield stress ``yield_stress`` (Pa)."""
    mu, lam = _lame(youngs, poisson)
    # Largest deviatoric Hencky strain norm: |dev tau| = 2 mu |dev eps| <= sqrt(2/3) sigma_y.
    yield_strain = math.sqrt(2 / 3) * yield_stress / (2 * mu)
    return {"mu": mu, "lam": lam, "param_a": yield_strain, "param_b": np.zeros_like(mu)}


class VonMisesGoop(_Elastic):
    """Goop: Hencky elasticity with von Mises plasticity; flows where the deviatoric stress
    exceeds ``yield_stress`` and keeps its volume while it flows (a Bingham-like paste)."""

    name: ClassVar[str] = "von_mises"
    kernel_id: ClassVar[int] = 2
    density: float = Field(default=1000.0, gt=0)
    youngs_modulus: float = Field(default=2.0e4, gt=0)
    poisson_ratio: float = Field(default=0.3, ge=0, lt=0.5)
    yield_stress: float = Field(default=300.0, gt=0, description="Pa, uniaxial (von Mises)")

    @staticmethod
    def kernel_parameters(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return _von_mises_arrays(values["youngs_modulus"], values["poisson_ratio"], values["yield_stress"])


class UndrainedClay(_Elastic):
    """Clay loaded faster than it drains: Hencky elasticity, and yield at the undrained shear
    strength c_u whatever the pressure (total-stress, Tresca-like), the usual model of soft-clay
    slides. It is the von Mises return map with sigma_y = sqrt(3) c_u, which equals Tresca in pure
    shear. ``cohesion`` is in kPa, the unit clay is reported in (values near 1 make good features)."""

    name: ClassVar[str] = "tresca"
    kernel_id: ClassVar[int] = VonMisesGoop.kernel_id
    density: float = Field(default=1800.0, gt=0)
    youngs_modulus: float = Field(default=1.0e6, gt=0)
    poisson_ratio: float = Field(default=0.3, ge=0, lt=0.5)
    cohesion: float = Field(default=1.0, gt=0, description="kPa, undrained shear strength c_u")

    @staticmethod
    def kernel_parameters(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        yield_stress = math.sqrt(3) * 1e3 * values["cohesion"]
        return _von_mises_arrays(values["youngs_modulus"], values["poisson_ratio"], yield_stress)


RIGID = "rigid"
"""The model name of kinematic bodies: prescribed motion, felt by particles through frictional contact.
They are grid boundary conditions, not MPM particles, so they have no parameters here."""


MODELS: dict[str, type[ConstitutiveModel]] = {
    m.name: m for m in (DruckerPragerSand, WeaklyCompressibleFluid, VonMisesGoop, UndrainedClay)
}
"""Constitutive models of MPM particles, by the name materials give in ``constitutive_model``."""
