"""A cohesive clay: a granular material whose grains stick together."""

from __future__ import annotations

from gns_framework.contracts import Material, MaterialProperty

COHESION = MaterialProperty(
    name="cohesion",
    description="cohesion of the clay, the shear strength at zero normal stress (may vary per particle)",
    unit="kPa",
    default=10.0,
)


class Clay(Material):
    """Cohesive clay. Particle type 8 (3, 5, 6 and 7 are rigid, water, sand and goop)."""

    name = "clay"
    particle_type = 8
    properties = (COHESION,)
    description = "cohesive clay; cohesion may vary per particle"
