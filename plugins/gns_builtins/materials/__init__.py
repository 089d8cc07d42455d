"""Built-in materials, with the particle-type ids of the public GNS datasets."""

from __future__ import annotations

from gns_framework.contracts import Material, MaterialProperty
from gns_framework.hookspecs import hookimpl

FRICTION = MaterialProperty(
    name="friction",
    description="tan of the internal friction angle (geoelements' material_property)",
    unit="1",
    default=0.5773502691896257,
)


class RigidBoundary(Material):
    """Walls and obstacles: positions are prescribed, never predicted."""

    name = "rigid"
    particle_type = 3
    kinematic = True
    description = "kinematic rigid boundary / obstacle particles (prescribed motion)"
    constitutive_model = "rigid"


class Water(Material):
    name = "water"
    particle_type = 5
    description = "Newtonian fluid (WaterDrop, WaterRamps)"
    constitutive_model = "weakly_compressible"
    physical_parameters = {"density": 1000.0, "bulk_modulus": 2.0e5, "eos_exponent": 7.0}


class Sand(Material):
    name = "sand"
    particle_type = 6
    granular = True
    properties = (FRICTION,)
    description = "granular Drucker-Prager material; friction may vary per particle"
    constitutive_model = "drucker_prager"
    physical_parameters = {"density": 2200.0, "youngs_modulus": 3.537e5, "poisson_ratio": 0.3}


class Goop(Material):
    name = "goop"
    particle_type = 7
    description = "viscoplastic material (Goop)"
    constitutive_model = "von_mises"
    physical_parameters = {"density": 1000.0, "youngs_modulus": 2.0e4, "poisson_ratio": 0.3}


@hookimpl
def gns_materials():
    return [RigidBoundary, Water, Sand, Goop]
