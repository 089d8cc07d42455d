"""Goop: the viscoplastic (von Mises) material of DeepMind's Goop dataset."""

from __future__ import annotations

from typing import ClassVar

from gns_framework.contracts import Material


class Goop(Material):
    name = "goop"
    particle_type = 7
    description = "viscoplastic material (Goop)"
    constitutive_model = "von_mises"
    physical_parameters: ClassVar[dict[str, float]] = {"density": 1000.0, "youngs_modulus": 2.0e4, "poisson_ratio": 0.3}
