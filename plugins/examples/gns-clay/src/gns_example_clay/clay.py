"""A cohesive clay: a granular material whose grains stick together."""

from __future__ import annotations

from typing import ClassVar

from gns_framework.contracts import Material, MaterialProperty

COHESION = MaterialProperty(
    name="cohesion",
    description="undrained shear strength c_u of the clay (may vary per particle)",
    unit="kPa",
    default=1.0,
)


class Clay(Material):
    """Cohesive clay. Particle type 8 (3, 5, 6 and 7 are rigid, water, sand and goop).

    The MLS-MPM simulates it with the built-in ``tresca`` model (undrained: yield at c_u
    whatever the pressure); ``cohesion`` is that model's parameter, so a scene's
    ``properties: {cohesion: ...}`` sets both the simulated strength and the feature.
    """

    name = "clay"
    particle_type = 8
    properties = (COHESION,)
    description = "cohesive clay (undrained); cohesion may vary per particle"
    constitutive_model = "tresca"
    physical_parameters: ClassVar[dict[str, float]] = {"density": 1800.0, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3}
