"""Rigid boundary particles: walls and obstacles whose motion is given, never predicted."""

from __future__ import annotations

from gns_framework.contracts import Material


class RigidBoundary(Material):
    """Walls and obstacles: positions are prescribed, never predicted."""

    name = "rigid"
    particle_type = 3
    kinematic = True
    description = "kinematic rigid boundary / obstacle particles (prescribed motion)"
    constitutive_model = "rigid"
