"""The bodies of a scene spec: material blocks filled with particles, and kinematic obstacles."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from .scene_values import Count, Range, Spec, Value


def no_range() -> Range:
    """The fixed value 0 (a default angle)."""
    return Range(range=(0.0, 0.0))


class Block(Spec):
    """A body of one material, filled with particles at the start."""

    material: str = Field(description="registered material name")
    count: Count = Field(
        default_factory=lambda: Range(range=(1, 1)),
        description="how many such blocks, each drawn on its own; {range: [low, high]} draws the number",
    )
    shape: Literal["box", "ellipsoid"] = Field(default="box", description="ellipsoid: inscribed in the box")
    position: list[Value] = Field(description="(d,) lower corner of the bounding box before rotation, metres")
    size: list[Value] = Field(description="(d,) edge lengths of the bounding box, metres")
    angle: Value = Field(
        default_factory=no_range, description="rotation about the box centre, degrees, in the x-y plane"
    )
    velocity: list[Value] | None = Field(default=None, description="(d,) initial velocity, m/s")
    properties: dict[str, Value] = Field(
        default_factory=dict, description="material properties, recorded per particle as model inputs"
    )
    parameters: dict[str, Value] = Field(
        default_factory=dict, description="constitutive-parameter overrides for this block, not recorded"
    )


SHAPED = ("polygon", "plane")
"""Obstacle shapes that are static and take no ``size``."""


class Obstacle(Spec):
    """A kinematic rigid body: prescribed motion, Coulomb friction, recorded as kinematic particles.

    ``box`` and ``ellipsoid`` (a disc or sphere when the sizes are equal) fill
    the box at ``position`` of edges ``size``, turned by ``angle`` about its
    centre. ``polygon`` (2D) has ``vertices`` relative to ``position``, turned
    by ``angle`` about it. ``plane`` is the half-space below the surface through
    ``position`` that rises at ``angle`` along +x (an inclined plane, a ramp).
    Only unrotated boxes and ellipsoids may move; the other shapes are static.
    """

    material: str = Field(description="registered kinematic material name")
    count: Count = Field(
        default_factory=lambda: Range(range=(1, 1)),
        description="how many such obstacles, each drawn on its own; {range: [0, 1]} makes one optional",
    )
    shape: Literal["box", "ellipsoid", "polygon", "plane"] = "box"
    position: list[Value] = Field(
        description="(d,) box/ellipsoid: lower corner before rotation at t = 0; polygon: origin of the vertices; "
        "plane: a point on the surface; metres"
    )
    size: list[Value] | None = Field(default=None, description="(d,) edge lengths of a box or ellipsoid, metres")
    angle: Value = Field(
        default_factory=no_range, description="rotation (box, ellipsoid, polygon) or slope (plane), degrees"
    )
    vertices: list[tuple[float, float]] | None = Field(
        default=None, description="(n, 2) polygon corners in the x-y plane relative to position, metres"
    )
    velocity: list[Value] | None = Field(default=None, description="(d,) constant velocity, m/s")
    friction: Value = Field(default_factory=lambda: Range(range=(0.3, 0.3)), description="Coulomb coefficient")
    record_friction: bool = Field(
        default=False,
        description="record the surface's Coulomb coefficient as its particles' friction property, a model input "
        "(as a wall's is): where the friction is drawn, a model that cannot see it cannot tell a surface the sand "
        "slides over from one that holds it",
    )

    @property
    def is_static_shape(self) -> bool:
        """Whether the body must stay put: a polygon, a plane, or a rotated box or ellipsoid."""
        return self.shape in SHAPED or not (self.angle.is_fixed and self.angle.low == 0.0)
