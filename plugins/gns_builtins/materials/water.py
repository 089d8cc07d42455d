"""Water: the Newtonian fluid of DeepMind's WaterDrop and WaterRamps datasets."""

from __future__ import annotations

from typing import ClassVar

from gns_framework.contracts import Material


class Water(Material):
    name = "water"
    particle_type = 5
    description = "Newtonian fluid (WaterDrop, WaterRamps)"
    constitutive_model = "weakly_compressible"
    physical_parameters: ClassVar[dict[str, float]] = {"density": 1000.0, "bulk_modulus": 2.0e5, "eos_exponent": 7.0}
