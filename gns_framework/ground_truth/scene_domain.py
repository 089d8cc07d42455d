"""The domain of a scene spec: its box (fixed or drawn), grid, walls and their conditions, and time stepping."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    BeforeValidator,
    Discriminator,
    Field,
    Tag,
    model_validator,
)

from .scene_values import Spec, Value, Weighted


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
    def _ordered(self) -> WallRange:
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


class WallChoice(Weighted):
    """One of several face conditions picked per trajectory (``weights``: their probabilities)."""

    one_of: list[WallOption] = Field(min_length=1)


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
        return [(lo, lo + e.low) for (lo, _), e in zip(self.bounds, self.extent, strict=True)]

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

    def drawn(self, extent: list[float] | None, walls: dict[str, float | str]) -> Domain:
        """This domain with its extent and face conditions fixed: what one trajectory runs in.

        A drawn extent is rounded to whole cells (at least one), so that each wall lies on a
        grid node as it does in a fixed domain, and the recorded bounds are the simulated walls.
        """
        dx = self.cell_size
        bounds = self.bounds
        if extent is not None:
            bounds = [(lo, lo + max(1, round(e / dx)) * dx) for (lo, _), e in zip(self.bounds, extent, strict=True)]
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
