"""Sand: a granular Drucker-Prager material whose friction may vary per particle."""

from __future__ import annotations

from typing import ClassVar

from gns_framework.contracts import Material, MaterialProperty

FRICTION = MaterialProperty(
    name="friction",
    description="tan of the internal friction angle (geoelements' material_property)",
    unit="1",
    default=0.5773502691896257,
)


class Sand(Material):
    name = "sand"
    particle_type = 6
    granular = True
    properties = (FRICTION,)
    description = "granular Drucker-Prager material; friction may vary per particle"
    constitutive_model = "drucker_prager"
    physical_parameters: ClassVar[dict[str, float]] = {
        "density": 2200.0,
        "youngs_modulus": 3.537e5,
        "poisson_ratio": 0.3,
    }
