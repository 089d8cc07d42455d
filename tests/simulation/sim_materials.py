"""The built-in materials with the simulator attributes proposed for them (docs/ground_truth.md).

Registered in place of ``builtin-materials`` so the simulator tests run against
the same names, particle types and properties as the built-ins.
"""

from __future__ import annotations

from gns_builtins import materials as builtin

from gns_framework.hookspecs import hookimpl


class Water(builtin.Water):
    constitutive_model = "weakly_compressible"
    physical_parameters = {"density": 1000.0, "bulk_modulus": 2.0e5, "eos_exponent": 7.0}


class Sand(builtin.Sand):
    constitutive_model = "drucker_prager"
    physical_parameters = {"density": 2200.0, "youngs_modulus": 3.537e5, "poisson_ratio": 0.3}


class Goop(builtin.Goop):
    constitutive_model = "von_mises"
    physical_parameters = {"density": 1000.0, "youngs_modulus": 2.0e4, "poisson_ratio": 0.3}


class Rigid(builtin.RigidBoundary):
    constitutive_model = "rigid"


@hookimpl
def gns_materials():
    return [Water, Sand, Goop, Rigid]
