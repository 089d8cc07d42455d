"""Scene specs: the YAML a ground-truth simulator turns into trajectories.

A scene names its domain, grid, time stepping, material blocks and kinematic
obstacles. Any number in a block or obstacle may instead be a random range
``{range: [low, high]}`` drawn once per trajectory (``per: particle`` draws one
value per particle, for material properties), which gives a dataset its variety.
``{one_of: [a, b, ...]}`` picks one of its options (numbers or ranges) per
trajectory. A position along an axis may be ``{span: [low, high]}``, a fraction
of the room the body leaves free there (0: against the lower wall, 1: against the
upper one), so bodies stay inside domains whose size is itself drawn
(``domain.extent``). A block or obstacle with ``count`` is drawn that many times
(a range of integers draws the count), and ``no_overlap`` keeps bodies apart.
Each face of the domain may draw its condition (``{one_of: [slip, {range: [0.3, 0.6]}]}``).

Validation reports every problem at once, each with its location
(``blocks[1].size: ...``) and a "did you mean" for misspelt keys.

Units are SI: metres, seconds, kilograms; friction is a coefficient (tan of
the friction angle). Angles of rotated bodies and inclined planes are in
degrees, counter-clockwise in the x-y plane (about the z axis in 3D, y up).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    Field,
    ValidationError,
)

from ..config.problems import problems_from
from ..config.yaml_files import load_yaml_mapping
from ..errors import RecipeError
from ..specs import ComponentSpec
from .scene_bodies import SHAPED, Block, Obstacle, no_range
from .scene_domain import FACES, Domain, Time, WallChoice, WallCondition, WallRange, Walls
from .scene_values import Count, OneOf, Range, Span, Spec, Value, is_spanned

__all__ = [
    "FACES",
    "SHAPED",
    "Block",
    "Count",
    "Domain",
    "Obstacle",
    "OneOf",
    "Range",
    "SceneSpec",
    "Span",
    "Spec",
    "Time",
    "Value",
    "WallChoice",
    "WallCondition",
    "WallRange",
    "Walls",
    "is_spanned",
    "load_scene",
    "parse_scene",
]


class SceneSpec(Spec):
    """Everything a ground-truth simulator needs to generate one family of trajectories."""

    name: str = Field(default="scene", description="label written to the dataset metadata")
    dim: Literal[2, 3]
    domain: Domain
    time: Time
    gravity: list[float] | None = Field(default=None, description="(d,) m/s^2; default -9.81 along axis 1 (y up)")
    particles_per_cell: int = Field(default=2, ge=1, le=4, description="particles per cell along each axis")
    jitter: float = Field(default=0.2, ge=0, le=0.5, description="random offset of particles, in particle spacings")
    seed: int = Field(default=0, ge=0, description="trajectory seeds derive from it")
    simulator: ComponentSpec = Field(
        default_factory=lambda: ComponentSpec(name="mls_mpm"), description="simulator name and its parameters"
    )
    blocks: list[Block] = Field(min_length=1)
    obstacles: list[Obstacle] = Field(default_factory=list)
    no_overlap: bool = Field(
        default=False,
        description="draw bodies again until their boxes are a particle spacing apart (planes excepted)",
    )

    @property
    def gravity_vector(self) -> tuple[float, ...]:
        if self.gravity is not None:
            return tuple(self.gravity)
        return tuple(-9.81 if axis == 1 else 0.0 for axis in range(self.dim))

    @property
    def particle_spacing(self) -> float:
        """Distance between neighbouring particles at rest, metres."""
        return self.domain.cell_size / self.particles_per_cell

    @property
    def property_names(self) -> tuple[str, ...]:
        """Material properties the scene sets, in first-use order (the material_property columns): the blocks',
        then ``friction`` where an obstacle records its surface's."""
        names: dict[str, None] = {}
        for block in self.blocks:
            names.update(dict.fromkeys(block.properties))
        if any(obstacle.record_friction for obstacle in self.obstacles):
            names["friction"] = None
        return tuple(names)

    def material_uses(self) -> list[tuple[str, str]]:
        """(location, material name) of every block and obstacle."""
        uses = [(f"blocks[{i}]", b.material) for i, b in enumerate(self.blocks)]
        return uses + [(f"obstacles[{i}]", o.material) for i, o in enumerate(self.obstacles)]

    def problems(self) -> list[tuple[str, str]]:
        """Consistency problems the field types cannot express (dimensions, placement)."""
        found: list[tuple[str, str]] = []
        d = self.dim

        def need_dim(where: str, values: list | None) -> bool:
            if values is not None and len(values) != d:
                found.append((where, f"expected {d} values (dim = {d}), got {len(values)}"))
                return False
            return True

        bounds_ok = need_dim("domain.bounds", self.domain.bounds)
        for axis, (lo, hi) in enumerate(self.domain.bounds):
            if not lo < hi:
                found.append((f"domain.bounds[{axis}]", f"lower must be below upper, got {[lo, hi]}"))
                bounds_ok = False
        need_dim("gravity", self.gravity)
        for face in FACES[2 * d :]:
            if getattr(self.domain.walls, face) is not None:
                found.append((f"domain.walls.{face}", f"a {d}D domain has faces {', '.join(FACES[: 2 * d])} only"))
        if self.domain.extent is not None and need_dim("domain.extent", self.domain.extent) and bounds_ok:
            for axis, (value, (lo, hi)) in enumerate(zip(self.domain.extent, self.domain.bounds, strict=True)):
                where = f"domain.extent[{axis}]"
                if is_spanned(value) or value.per == "particle":
                    found.append((where, "an extent is a length in metres: a number, {range: ...} or {one_of: ...}"))
                elif value.low <= 0 or value.high > hi - lo + 1e-12:
                    found.append(
                        (
                            where,
                            f"must lie in (0, {hi - lo:g}] (the bounds' extent), got [{value.low:g}, {value.high:g}]",
                        )
                    )
        found += self._count_problems()
        for i, obstacle in enumerate(self.obstacles):
            found += _shape_problems(f"obstacles[{i}]", obstacle, d)
        for where, body in [(f"blocks[{i}]", b) for i, b in enumerate(self.blocks)] + [
            (f"obstacles[{i}]", o) for i, o in enumerate(self.obstacles)
        ]:
            shaped = need_dim(f"{where}.position", body.position) & need_dim(f"{where}.size", body.size)
            shaped &= need_dim(f"{where}.velocity", body.velocity)
            for field in ("position", "size", "velocity"):
                for axis, value in enumerate(getattr(body, field) or []):
                    if value.per == "particle":
                        found.append((f"{where}.{field}[{axis}]", "per: particle applies to properties only"))
                    if field != "position" and is_spanned(value):
                        found.append((f"{where}.{field}[{axis}]", "span applies to positions only"))
            for field in ("angle", "friction"):
                setting = getattr(body, field, None)
                if setting is not None and setting.per == "particle":
                    found.append((f"{where}.{field}", "per: particle applies to properties only"))
                if setting is not None and is_spanned(setting):
                    found.append((f"{where}.{field}", "span applies to positions only"))
            for field in ("properties", "parameters"):
                for name, value in (getattr(body, field, None) or {}).items():
                    if is_spanned(value):
                        found.append((f"{where}.{field}.{name}", "span applies to positions only"))
            spanned = any(is_spanned(v) for v in body.position)
            if spanned and not (body.angle.is_fixed and body.angle.low == 0.0):
                found.append((f"{where}.position", "a span places a body's unrotated box: it takes no angle"))
            if spanned and isinstance(body, Obstacle) and body.shape == "plane":
                found.append((f"{where}.position", "a plane is unbounded: place it with numbers or ranges, not spans"))
            for axis, size in enumerate(body.size or []):
                if size.low <= 0:
                    found.append((f"{where}.size[{axis}]", f"must be > 0, got {size.low}"))
            if isinstance(body, Obstacle) and body.is_static_shape:
                continue  # static shapes record only their particles inside the domain
            if shaped and bounds_ok and body.size is not None:
                duration = (self.time.frames - 1) * self.time.frame_dt
                found += _outside_domain(where, body, self.domain.smallest_bounds, duration)
        return found

    def _count_problems(self) -> list[tuple[str, str]]:
        """Counts are whole numbers >= 0, and every trajectory has at least one block."""
        found = []
        for where, body in self.bodies_with_location():
            low, high = body.count.range
            if low < 0 or low != int(low) or high != int(high) or body.count.per == "particle":
                found.append(
                    (
                        f"{where}.count",
                        f"expected a whole number >= 0 or {{range: [low, high]}} of them, got {[low, high]}",
                    )
                )
        if found:
            return found
        if sum(int(block.count.low) for block in self.blocks) < 1:
            found.append(("blocks", "every trajectory needs a block: some block's count must be at least 1"))
        return found

    def bodies_with_location(self) -> list[tuple[str, Block | Obstacle]]:
        """(location, body) of every block and obstacle, in drawing order."""
        return [(f"blocks[{i}]", b) for i, b in enumerate(self.blocks)] + [
            (f"obstacles[{i}]", o) for i, o in enumerate(self.obstacles)
        ]


def _shape_problems(where: str, obstacle: Obstacle, dim: int) -> list[tuple[str, str]]:
    """What an obstacle's shape needs: size for boxes and ellipsoids, vertices for polygons, no motion when shaped."""
    found = []
    if obstacle.shape in SHAPED:
        if obstacle.size is not None:
            found.append((f"{where}.size", f"a {obstacle.shape} takes no size"))
    elif obstacle.size is None:
        found.append((f"{where}.size", f"a {obstacle.shape} needs size: (d,) edge lengths"))
    if obstacle.shape == "polygon":
        if dim != 2:
            found.append((f"{where}.shape", "polygons are 2D; in 3D use box, ellipsoid or plane"))
        if obstacle.vertices is None or len(obstacle.vertices) < 3:
            found.append((f"{where}.vertices", "a polygon needs at least 3 vertices [[x, y], ...]"))
    elif obstacle.vertices is not None:
        found.append((f"{where}.vertices", f"only polygons take vertices, not a {obstacle.shape}"))
    if obstacle.shape == "plane" and not all(-90 < a < 90 for a in (obstacle.angle.low, obstacle.angle.high)):
        slope = [obstacle.angle.low, obstacle.angle.high]
        found.append((f"{where}.angle", f"a plane's slope must lie in (-90, 90) degrees, got {slope}"))
    moving = obstacle.velocity is not None and any(v.low != 0 or v.high != 0 for v in obstacle.velocity)
    if moving and obstacle.is_static_shape:
        found.append((f"{where}.velocity", "polygons, planes and rotated bodies are static: velocity must be 0"))
    return found


def _outside_domain(where: str, body: Block | Obstacle, bounds: list[tuple[float, float]], duration: float):
    """Axes where a body's box leaves the domain: its swept box for a moving obstacle, its turned box
    for a rotated block."""
    found = []
    assert body.size is not None  # the caller checks it
    velocity = body.velocity or [no_range()] * len(bounds)
    turned = isinstance(body, Block) and not (body.angle.is_fixed and body.angle.low == 0.0)
    reach = _rotated_half_extents(body) if turned and isinstance(body, Block) else None
    for axis, ((lo, hi), pos, size, vel) in enumerate(zip(bounds, body.position, body.size, velocity, strict=True)):
        if is_spanned(pos):
            if size.high > hi - lo:
                found.append(
                    (
                        f"{where}.size[{axis}]",
                        f"up to {size.high:g} does not fit the domain's {hi - lo:g} on axis {axis}",
                    )
                )
            continue  # a span keeps the body inside by construction
        sweep = (0.0, 0.0) if isinstance(body, Block) else (vel.low * duration, vel.high * duration)
        low, high = pos.low + min(0.0, sweep[0]), pos.high + size.high + max(0.0, sweep[1])
        if reach is not None and axis < 2:
            # The box turns about its centre: it reaches the centre +- the turned half extent.
            low = pos.low + size.low / 2 - reach[axis]
            high = pos.high + size.high / 2 + reach[axis]
        if low < lo or high > hi:
            found.append(
                (
                    f"{where}.position[{axis}]",
                    f"spans [{low:g}, {high:g}] on axis {axis}, outside the domain [{lo:g}, {hi:g}]",
                )
            )
    return found


def _rotated_half_extents(block: Block) -> tuple[float, float]:
    """Largest x and y half extents of the block's largest box over its angle range.

    Along x the extent a |cos t| + b |sin t| peaks at the ends of the range or
    where tan t = +-b / a (mod 90 degrees), so those angles are all it needs.
    """
    a, b = block.size[0].high / 2, block.size[1].high / 2
    low, high = block.angle.low, block.angle.high
    candidates = {low, high}
    for critical in (math.degrees(math.atan2(b, a)), math.degrees(math.atan2(a, b))):
        for turn in range(math.floor((low - critical) / 90) - 1, math.ceil((high + critical) / 90) + 2):
            for angle in (turn * 90 + critical, turn * 90 - critical):
                if low <= angle <= high:
                    candidates.add(angle)
    radians = [math.radians(t) for t in candidates]
    return (
        max(a * abs(math.cos(t)) + b * abs(math.sin(t)) for t in radians),
        max(a * abs(math.sin(t)) + b * abs(math.cos(t)) for t in radians),
    )


def parse_scene(raw: Any, source: str | Path = "<scene>") -> SceneSpec:
    """Validate a scene mapping; every problem is reported at once in a RecipeError."""
    if not isinstance(raw, dict):
        raise RecipeError(source, [("", f"expected a mapping at the top level, got {type(raw).__name__}")])
    try:
        scene = SceneSpec.model_validate(raw)
    except ValidationError as exc:
        raise RecipeError(source, problems_from(exc, SceneSpec)) from None
    problems = scene.problems()
    if problems:
        raise RecipeError(source, problems)
    return scene


def load_scene(path: str | Path) -> SceneSpec:
    """Read and validate a scene YAML file (duplicate keys are errors too)."""
    return parse_scene(load_yaml_mapping(path), path)
