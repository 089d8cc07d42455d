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


class Water(Material):
    name = "water"
    particle_type = 5
    description = "Newtonian fluid (WaterDrop, WaterRamps)"


class Sand(Material):
    name = "sand"
    particle_type = 6
    properties = (FRICTION,)
    description = "granular Drucker-Prager material; friction may vary per particle"


class Goop(Material):
    name = "goop"
    particle_type = 7
    description = "viscoplastic material (Goop)"


@hookimpl
def gns_materials():
    return [RigidBoundary, Water, Sand, Goop]
