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
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    model_validator,
)

from ..config.problems import problems_from
from ..config.yaml_files import load_yaml_mapping
from ..errors import RecipeError
from ..specs import ComponentSpec


class Spec(BaseModel):
    """Base of every scene-spec section: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True, coerce_numbers_to_str=True)


class Range(Spec):
    """A value drawn uniformly from ``[low, high]``; a plain number is a range of width 0."""

    range: tuple[float, float]
    per: Literal["trajectory", "particle"] = "trajectory"

    @model_validator(mode="after")
    def _ordered(self) -> "Range":
        if self.range[0] > self.range[1]:
            raise ValueError(f"range must be [low, high] with low <= high, got {list(self.range)}")
        return self

    @property
    def low(self) -> float:
        return self.range[0]

    @property
    def high(self) -> float:
        return self.range[1]

    @property
    def is_fixed(self) -> bool:
        return self.range[0] == self.range[1]


class Span(Spec):
    """A position along one axis as a fraction of the room a body leaves free there.

    The body's lower corner is ``lower wall + u * (domain extent - body size)`` with
    ``u`` drawn from ``[low, high]`` within [0, 1]: 0 puts it against the lower wall,
    1 against the upper one. Only positions take spans.
    """

    span: tuple[float, float]

    @model_validator(mode="before")
    @classmethod
    def _scalar(cls, data: Any) -> Any:
        if isinstance(data, dict) and isinstance(data.get("span"), (int, float)) and not isinstance(data["span"], bool):
            return {**data, "span": (data["span"], data["span"])}
        return data

    @model_validator(mode="after")
    def _fraction(self) -> "Span":
        if not 0.0 <= self.span[0] <= self.span[1] <= 1.0:
            raise ValueError(f"span must be [low, high] with 0 <= low <= high <= 1, got {list(self.span)}")
        return self

    per: Literal["trajectory"] = "trajectory"

    @property
    def low(self) -> float:
        return self.span[0]

    @property
    def high(self) -> float:
        return self.span[1]

    @property
    def is_fixed(self) -> bool:
        return self.span[0] == self.span[1]


def _number_or_range(value: Any) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"expected a number, {{range: [low, high]}} or {{span: [low, high]}}, got {value!r}")
    if isinstance(value, (int, float)):
        return {"range": (value, value)}
    if isinstance(value, (dict, Range, Span)):
        return value
    raise ValueError(f"expected a number, {{range: [low, high]}} or {{span: [low, high]}}, got {value!r}")


def _single_kind(value: Any) -> str:
    """Which of Range and Span a mapping is (by its key), so errors speak of that one only.

    Tags start with ``@``, which problem locations leave out (:mod:`gns_framework.config.problems`).
    """
    if isinstance(value, Span) or (isinstance(value, dict) and "span" in value):
        return "@span"
    return "@range"


Single = Annotated[
    Annotated[Range, Tag("@range")] | Annotated[Span, Tag("@span")],
    Discriminator(_single_kind),
    BeforeValidator(_number_or_range),
]
"""A number, ``{range: [low, high], per: trajectory|particle}`` or ``{span: [low, high]}``."""


def _check_weights(weights: list[float] | None, options: int) -> None:
    """The probabilities of a ``one_of``: one per option, >= 0, with a positive sum (None: equal)."""
    if weights is None:
        return
    if len(weights) != options:
        raise ValueError(f"weights: expected {options} values (one per option), got {len(weights)}")
    if min(weights) < 0 or sum(weights) <= 0:
        raise ValueError(f"weights must be >= 0 with a positive sum, got {weights}")


class OneOf(Spec):
    """One of several options (numbers, ranges or spans), picked per trajectory, then drawn.

    ``weights`` (default: equal) are the options' probabilities, normalised.
    """

    one_of: list[Single] = Field(min_length=1)
    weights: list[float] | None = None

    @model_validator(mode="after")
    def _weights(self) -> "OneOf":
        _check_weights(self.weights, len(self.one_of))
        return self

    per: Literal["trajectory"] = "trajectory"

    @property
    def low(self) -> float:
        return min(option.low for option in self.one_of)

    @property
    def high(self) -> float:
        return max(option.high for option in self.one_of)

    @property
    def is_fixed(self) -> bool:
        return len(self.one_of) == 1 and self.one_of[0].is_fixed

    @property
    def has_span(self) -> bool:
        return any(isinstance(option, Span) for option in self.one_of)


def _value_kind(value: Any) -> str:
    if isinstance(value, OneOf) or (isinstance(value, dict) and "one_of" in value):
        return "@one_of"
    return _single_kind(value)


Value = Annotated[
    Annotated[Range, Tag("@range")] | Annotated[Span, Tag("@span")] | Annotated[OneOf, Tag("@one_of")],
    Discriminator(_value_kind),
    BeforeValidator(_number_or_range),
]
"""A number, ``{range: [low, high], per: trajectory|particle}``, ``{span: [low, high]}`` (positions)
or ``{one_of: [option, ...], weights: [...]}``."""


def is_spanned(value: Range | Span | OneOf) -> bool:
    """Whether a value is (or may pick) a span, a position relative to the domain."""
    return isinstance(value, Span) or (isinstance(value, OneOf) and value.has_span)


def _number_of_bodies(value: Any) -> Any:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return {"range": (value, value)}
    return value


Count = Annotated[Range, BeforeValidator(_number_of_bodies)]
"""A whole number of bodies, or ``{range: [low, high]}`` of whole numbers drawn per trajectory."""


def _wall_condition(value: Any) -> Any:
    if isinstance(value, str) and value in ("slip", "no_slip"):
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0:
        return float(value)
    raise ValueError("expected a Coulomb friction coefficient >= 0, 'slip' or 'no_slip'")


WallCondition = Annotated[float | Literal["slip", "no_slip"], BeforeValidator(_wall_condition)]
"""A face of the domain: a Coulomb friction coefficient, ``slip`` (frictionless) or ``no_slip``."""


class WallRange(Spec):
    """A face's Coulomb friction coefficient drawn per trajectory from ``[low, high]``."""

    range: tuple[float, float]

    @model_validator(mode="after")
    def _ordered(self) -> "WallRange":
        if not 0 <= self.range[0] <= self.range[1]:
            raise ValueError(f"range must be [low, high] with 0 <= low <= high, got {list(self.range)}")
        return self


def _wall_kind(value: Any) -> str:
    if isinstance(value, WallChoice) or (isinstance(value, dict) and "one_of" in value):
        return "@one_of"
    if isinstance(value, (WallRange, dict)):
        return "@range"
    return "@condition"


WallOption = Annotated[
    Annotated[WallRange, Tag("@range")] | Annotated[WallCondition, Tag("@condition")], Discriminator(_wall_kind)
]


class WallChoice(Spec):
    """One of several face conditions picked per trajectory (``weights``: their probabilities)."""

    one_of: list[WallOption] = Field(min_length=1)
    weights: list[float] | None = None

    @model_validator(mode="after")
    def _weights(self) -> "WallChoice":
        _check_weights(self.weights, len(self.one_of))
        return self


WallDraw = Annotated[
    Annotated[WallChoice, Tag("@one_of")]
    | Annotated[WallRange, Tag("@range")]
    | Annotated[WallCondition, Tag("@condition")],
    Discriminator(_wall_kind),
]
"""A face condition, ``{range: [low, high]}`` of friction, or ``{one_of: [slip, {range: ...}, ...]}``."""

FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
"""Domain faces, in the order (axis 0 lower, axis 0 upper, axis 1 lower, ...)."""


class Walls(Spec):
    """Conditions of individual faces of the domain; a face not named keeps ``wall_friction``.

    A friction coefficient mu: approaching motion stops and the tangential
    velocity loses mu times the removed normal speed (Coulomb). ``slip``: mu = 0.
    ``no_slip``: the tangential velocity at the face is zero; the fluid may still
    leave the face.
    """

    x_min: WallDraw | None = None
    x_max: WallDraw | None = None
    y_min: WallDraw | None = None
    y_max: WallDraw | None = None
    z_min: WallDraw | None = None
    z_max: WallDraw | None = None

    @property
    def is_drawn(self) -> bool:
        """Whether some face draws its condition per trajectory."""
        return any(isinstance(getattr(self, face), (WallChoice, WallRange)) for face in FACES)


class Domain(Spec):
    """The box particles live in and the background grid that covers it.

    With ``extent`` the domain's size is drawn per trajectory: it spans
    ``[lower, lower + extent]`` on each axis, inside ``bounds`` (the largest domain),
    on a grid of the same cell size. Faces whose condition is drawn and drawn extents
    make a *drawn* domain per trajectory (:meth:`drawn`), fixed in every respect.
    """

    bounds: list[tuple[float, float]] = Field(
        description="(d, 2) lower and upper wall per axis, metres; with extent, the largest domain"
    )
    grid: int = Field(
        ge=4, le=4096, description="grid cells along the longest axis of bounds (cell size dx = longest / grid)"
    )
    extent: list[Value] | None = Field(
        default=None, description="(d,) edge lengths drawn per trajectory (at most the bounds'), metres"
    )
    wall_friction: float = Field(
        default=0.5, ge=0, description="Coulomb friction coefficient of every face that `walls` does not name"
    )
    walls: Walls = Field(
        default_factory=Walls, description="per-face conditions: x_min, x_max, y_min, ... (2 faces per axis)"
    )
    cell_size_override: float | None = Field(
        default=None, gt=0, description="dx of a drawn domain, metres (set by drawing; keeps the scene's dx)"
    )

    @property
    def cell_size(self) -> float:
        """dx in metres."""
        if self.cell_size_override is not None:
            return self.cell_size_override
        return max(hi - lo for lo, hi in self.bounds) / self.grid

    @property
    def is_drawn(self) -> bool:
        """Whether each trajectory draws its own domain (size or face conditions)."""
        return self.extent is not None or self.walls.is_drawn

    @property
    def smallest_bounds(self) -> list[tuple[float, float]]:
        """(d, 2) the smallest domain ``extent`` can draw (``bounds`` when it draws none)."""
        if self.extent is None or len(self.extent) != len(self.bounds):
            return list(self.bounds)
        return [(lo, lo + e.low) for (lo, _), e in zip(self.bounds, self.extent)]

    def wall_conditions(self) -> list[tuple[float, bool]]:
        """(friction coefficient, no-slip) of the 2 d faces, in ``FACES`` order; a fixed domain only."""
        if self.walls.is_drawn:
            raise ValueError("wall_conditions of a domain that draws its faces: draw the domain first (Domain.drawn)")
        conditions = []
        for face in FACES[: 2 * len(self.bounds)]:
            condition = getattr(self.walls, face)
            if condition is None:
                conditions.append((self.wall_friction, False))
            elif condition == "no_slip":
                conditions.append((0.0, True))
            else:
                conditions.append((0.0 if condition == "slip" else condition, False))
        return conditions

    def drawn(self, extent: list[float] | None, walls: dict[str, float | str]) -> "Domain":
        """This domain with its extent and face conditions fixed: what one trajectory runs in.

        A drawn extent is rounded to whole cells (at least one), so that each wall lies on a
        grid node as it does in a fixed domain, and the recorded bounds are the simulated walls.
        """
        dx = self.cell_size
        bounds = self.bounds
        if extent is not None:
            bounds = [(lo, lo + max(1, round(e / dx)) * dx) for (lo, _), e in zip(self.bounds, extent)]
        return self.model_copy(
            update={
                "bounds": [tuple(b) for b in bounds],
                "extent": None,
                "walls": Walls(**{face: walls.get(face, getattr(self.walls, face)) for face in FACES}),
                "cell_size_override": self.cell_size,
            }
        )


class Time(Spec):
    """Stored frames and the solver substeps between them."""

    frame_dt: float = Field(gt=0, description="seconds between stored frames")
    substeps: int = Field(ge=1, description="solver steps per stored frame")
    frames: int = Field(ge=3, description="stored frames per trajectory, the initial one included")

    @property
    def substep_dt(self) -> float:
        return self.frame_dt / self.substeps


def _zero() -> Range:
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
    angle: Value = Field(default_factory=_zero, description="rotation about the box centre, degrees, in the x-y plane")
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
        default_factory=_zero, description="rotation (box, ellipsoid, polygon) or slope (plane), degrees"
    )
    vertices: list[tuple[float, float]] | None = Field(
        default=None, description="(n, 2) polygon corners in the x-y plane relative to position, metres"
    )
    velocity: list[Value] | None = Field(default=None, description="(d,) constant velocity, m/s")
    friction: Value = Field(default_factory=lambda: Range(range=(0.3, 0.3)), description="Coulomb coefficient")

    @property
    def is_static_shape(self) -> bool:
        """Whether the body must stay put: a polygon, a plane, or a rotated box or ellipsoid."""
        return self.shape in SHAPED or not (self.angle.is_fixed and self.angle.low == 0.0)


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
        """Material properties the scene sets, in first-use order (the material_property columns)."""
        names: dict[str, None] = {}
        for block in self.blocks:
            names.update(dict.fromkeys(block.properties))
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
            for axis, (value, (lo, hi)) in enumerate(zip(self.domain.extent, self.domain.bounds)):
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

    def bodies_with_location(self) -> list[tuple[str, "Block | Obstacle"]]:
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
    velocity = body.velocity or [_zero()] * len(bounds)
    turned = isinstance(body, Block) and not (body.angle.is_fixed and body.angle.low == 0.0)
    reach = _rotated_half_extents(body) if turned and isinstance(body, Block) else None
    for axis, ((lo, hi), pos, size, vel) in enumerate(zip(bounds, body.position, body.size, velocity)):
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
