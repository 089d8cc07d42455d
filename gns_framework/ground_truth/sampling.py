"""Draw one concrete scene from a spec: random ranges resolved, bodies filled with particles.

Any ground-truth simulator can start from this; the draws depend only on the
spec and the seed, in a fixed order, so a seed always gives the same particles:
the domain's extent and face conditions first (axis by axis, face by face), then
each block and obstacle in the spec's order (its count, then each copy's
position, size, velocity, angle and values). A value that is fixed draws nothing,
so a scene without ranges always gives the same particles, and adding a range
to one body leaves the draws of the bodies before it as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..contracts import Material
from ..errors import GnsError
from ..limits import check_scene
from . import shapes
from .scene_spec import FACES, Block, Obstacle, OneOf, Range, SceneSpec, Span, WallChoice, WallRange

PLACEMENT_TRIES = 200
"""Draws of one body under ``no_overlap`` before the whole scene's bodies are drawn again."""

SCENE_TRIES = 50
"""Draws of all bodies under ``no_overlap`` before the scene is declared unplaceable."""


@dataclass(frozen=True)
class BodySample:
    """One block or obstacle as drawn for a trajectory.

    Attributes:
        location: where the body is in the spec (``blocks[0]``), for messages.
        material: registered material name.
        shape: ``box``, ``ellipsoid`` (inscribed in the box), ``polygon`` or ``plane``.
        lower: (d,) lower corner of the bounding box before rotation at t = 0;
            a polygon's vertex origin; a point on a plane's surface; metres.
        size: (d,) edge lengths of the bounding box (zeros for polygons and planes), metres.
        velocity: (d,) initial (blocks) or constant (obstacles) velocity, m/s.
        position: (n, d) float64 particle positions at t = 0.
        values: property and parameter name -> (n,) float64 per-particle values
            the spec sets for this body (an obstacle's ``friction`` where it records it).
        friction: Coulomb coefficient of an obstacle's surface (0 for blocks).
        angle: rotation about the box centre, or a plane's slope, degrees in the x-y plane.
        vertices: (m, 2) a polygon's corners, counter-clockwise, in the domain's frame, metres.
    """

    location: str
    material: str
    shape: str
    lower: np.ndarray
    size: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    friction: float = 0.0
    angle: float = 0.0
    vertices: np.ndarray | None = None

    @property
    def num_particles(self) -> int:
        return int(self.position.shape[0])


@dataclass(frozen=True)
class SceneSample:
    """A drawn scene: blocks' particles first, then obstacles' (kinematic) particles.

    ``scene`` is the spec with its domain drawn (extent and face conditions fixed):
    what a simulator runs for this trajectory.
    """

    blocks: list[BodySample]
    obstacles: list[BodySample]
    property_names: tuple[str, ...]
    scene: SceneSpec | None = None

    @property
    def bounds(self) -> np.ndarray:
        """(d, 2) float32 lower and upper wall per axis of the drawn domain, metres."""
        assert self.scene is not None  # sample_scene draws it
        return np.asarray(self.scene.domain.bounds, dtype=np.float32)

    @property
    def walls(self) -> np.ndarray:
        """(2d, 2) float32 per face (``FACES`` order): Coulomb friction coefficient, 1 if no-slip else 0."""
        assert self.scene is not None  # sample_scene draws it
        return np.asarray(self.scene.domain.wall_conditions(), dtype=np.float32)

    @property
    def bodies(self) -> list[BodySample]:
        return self.blocks + self.obstacles

    @property
    def num_particles(self) -> int:
        return sum(b.num_particles for b in self.bodies)

    def particle_type(self, materials: dict[str, type[Material]]) -> np.ndarray:
        """(N,) int64 type id of every particle, from its material."""
        return np.concatenate(
            [np.full(b.num_particles, materials[b.material].particle_type, dtype=np.int64) for b in self.bodies]
        )

    def material_property(self, materials: dict[str, type[Material]]) -> np.ndarray | None:
        """(N, P) float32 recorded properties, columns ``property_names``; None when the scene sets none.

        A body that does not set a property gets its material's declared default,
        or 0 when its material does not have that property.
        """
        if not self.property_names:
            return None
        columns = []
        for name in self.property_names:
            column = []
            for body in self.bodies:
                if name in body.values:
                    column.append(body.values[name])
                else:
                    declared = {p.name: p.default for p in materials[body.material].properties}
                    column.append(np.full(body.num_particles, declared.get(name, 0.0)))
            columns.append(np.concatenate(column))
        return np.stack(columns, axis=1).astype(np.float32)


def _pick(options: list, weights: list[float] | None, rng: np.random.Generator):
    """One of ``options`` (probabilities ``weights``, default equal); a single option draws nothing."""
    if len(options) == 1:
        return options[0]
    p = None if weights is None else np.asarray(weights, dtype=np.float64) / sum(weights)
    return options[int(rng.choice(len(options), p=p))]


def _draw(value: Range | Span | OneOf, rng: np.random.Generator, count: int) -> np.ndarray:
    """(count,) draws; one shared draw unless the range is per particle. A span draws its fraction."""
    if isinstance(value, OneOf):
        value = _pick(value.one_of, value.weights, rng)
    if value.is_fixed:
        return np.full(count, value.low)
    if value.per == "particle":
        return rng.uniform(value.low, value.high, size=count)
    return np.full(count, rng.uniform(value.low, value.high))


def _draw_vector(values: list | None, rng: np.random.Generator, dim: int) -> np.ndarray:
    if values is None:
        return np.zeros(dim)
    return np.array([_draw(v, rng, 1)[0] for v in values])


def _draw_position(values: list, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(d,) drawn coordinates and (d,) whether each is a span fraction (placed once the size is known)."""
    coordinates, spanned = [], []
    for value in values:
        if isinstance(value, OneOf):
            value = _pick(value.one_of, value.weights, rng)
        coordinates.append(_draw(value, rng, 1)[0])
        spanned.append(isinstance(value, Span))
    return np.array(coordinates), np.array(spanned, dtype=bool)


def _draw_face(condition, rng: np.random.Generator) -> float | str:
    """A face's condition for one trajectory: a friction coefficient, ``slip`` or ``no_slip``."""
    if isinstance(condition, WallChoice):
        condition = _pick(condition.one_of, condition.weights, rng)
    if isinstance(condition, WallRange):
        low, high = condition.range
        return low if low == high else float(rng.uniform(low, high))
    return condition


def draw_domain(scene: SceneSpec, rng: np.random.Generator) -> SceneSpec:
    """``scene`` with its domain's extent and face conditions drawn; ``scene`` itself when it draws none."""
    domain = scene.domain
    if not domain.is_drawn:
        return scene
    extent = None if domain.extent is None else [float(_draw(e, rng, 1)[0]) for e in domain.extent]
    walls = {}
    for face in FACES[: 2 * scene.dim]:
        condition = getattr(domain.walls, face)
        if isinstance(condition, (WallChoice, WallRange)):
            walls[face] = _draw_face(condition, rng)
    return scene.model_copy(update={"domain": domain.drawn(extent, walls)})


def fill(shape: str, lower: np.ndarray, size: np.ndarray, spacing: float) -> np.ndarray:
    """(n, d) lattice points at ``spacing`` inside a box or its inscribed ellipsoid.

    Points sit at cell centres of a lattice anchored at ``lower``, so each
    particle stands for a volume ``spacing ** d``.
    """
    # int(): under numpy 1.x, round() of a numpy scalar is still a numpy float.
    counts = [max(1, int(round(s / spacing))) for s in size]  # noqa: RUF046
    axes = [lower[a] + (np.arange(n) + 0.5) * spacing for a, n in enumerate(counts)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(size))
    if shape == "ellipsoid":
        centre, radii = lower + size / 2, size / 2
        points = points[(((points - centre) / radii) ** 2).sum(axis=1) <= 1.0]
    return points


def _particles(
    body: Block | Obstacle,
    lower: np.ndarray,
    size: np.ndarray,
    angle: float,
    vertices: np.ndarray | None,
    scene: SceneSpec,
) -> np.ndarray:
    """(n, d) particles of a body at t = 0; a static shaped obstacle keeps those inside the domain.

    Boxes, ellipsoids and polygons are filled; a plane, being unbounded below,
    is recorded as ``particles_per_cell`` rows under its surface (one cell deep).
    """
    spacing = scene.particle_spacing
    bounds = np.array(scene.domain.bounds, dtype=np.float64)
    if body.shape == "plane":
        return shapes.plane_layer(lower, angle, bounds, spacing, scene.particles_per_cell)
    if body.shape == "polygon":
        assert vertices is not None  # a polygon has them (SceneSpec checks it)
        points = shapes.polygon_lattice(vertices, spacing)
    else:
        points = shapes.rotate_xy(fill(body.shape, lower, size, spacing), angle, lower + size / 2)
    if isinstance(body, Obstacle) and body.is_static_shape:
        points = points[shapes.inside(points, bounds)]
    return points


def _sample_body(location: str, body: Block | Obstacle, scene: SceneSpec, rng: np.random.Generator) -> BodySample:
    d = scene.dim
    lower, spanned = _draw_position(body.position, rng)
    size = _draw_vector(body.size, rng, d)
    velocity = _draw_vector(body.velocity, rng, d)
    angle = float(_draw(body.angle, rng, 1)[0])
    if spanned.any():
        lower = _placed(lower, spanned, _extent_of(body, size), scene)
        if isinstance(body, Obstacle) and body.vertices is not None:
            # A polygon's position is its vertices' origin: shift it so their box starts where placed.
            offset = np.zeros(d)
            offset[:2] = np.array(body.vertices, dtype=np.float64).min(axis=0)
            lower = np.where(spanned, lower - offset, lower)
    vertices = None
    if isinstance(body, Obstacle) and body.vertices is not None:
        corners = lower[:2] + np.array(body.vertices, dtype=np.float64)
        vertices = shapes.counter_clockwise(shapes.rotate_xy(corners, angle, lower[:2]))
    position = _particles(body, lower, size, angle, vertices, scene)
    if scene.jitter > 0 and isinstance(body, Block):
        position = position + rng.uniform(-scene.jitter, scene.jitter, position.shape) * scene.particle_spacing
    values = {}
    friction = 0.0
    if isinstance(body, Block):
        for name, value in {**body.properties, **body.parameters}.items():
            values[name] = _draw(value, rng, len(position))
    else:
        friction = float(_draw(body.friction, rng, 1)[0])
        if body.record_friction:
            values["friction"] = np.full(len(position), friction)
    return BodySample(
        location, body.material, body.shape, lower, size, velocity, position, values, friction, angle, vertices
    )


def _extent_of(body: Block | Obstacle, size: np.ndarray) -> np.ndarray:
    """(d,) edge lengths of a body's box before rotation; a polygon's are its corners' spread."""
    if isinstance(body, Obstacle) and body.vertices is not None:
        corners = np.array(body.vertices, dtype=np.float64)
        spread = np.zeros_like(size)
        spread[:2] = corners.max(axis=0) - corners.min(axis=0)
        return spread
    return size


def _placed(lower: np.ndarray, spanned: np.ndarray, extent: np.ndarray, scene: SceneSpec) -> np.ndarray:
    """``lower`` with each span fraction u turned into ``wall + u * (room - extent)`` on its axis."""
    bounds = np.array(scene.domain.bounds, dtype=np.float64)
    room = bounds[:, 1] - bounds[:, 0] - extent
    return np.where(spanned, bounds[:, 0] + lower * np.maximum(room, 0.0), lower)


def _box_of(sample: BodySample) -> tuple[np.ndarray, np.ndarray] | None:
    """(lower, upper) of the axis-aligned box a drawn body occupies; None for planes (unbounded)."""
    if sample.shape == "plane":
        return None
    points = sample.position
    if sample.vertices is not None:  # polygons are 2D
        return sample.vertices.min(axis=0), sample.vertices.max(axis=0)
    if sample.angle == 0.0:
        return sample.lower, sample.lower + sample.size
    if len(points) == 0:
        return None
    return points.min(axis=0), points.max(axis=0)


def _apart(box: tuple[np.ndarray, np.ndarray] | None, placed: list, gap: float) -> bool:
    """Whether ``box`` keeps at least ``gap`` from every box in ``placed`` along some axis."""
    if box is None:
        return True
    lower, upper = box
    for other in placed:
        if other is not None and np.all(lower < other[1] + gap) and np.all(other[0] < upper + gap):
            return False
    return True


def _sample_bodies(scene: SceneSpec, rng: np.random.Generator) -> tuple[list[BodySample], list[BodySample]] | None:
    """Every block and obstacle drawn (counts first); None when ``no_overlap`` could not place one."""
    blocks: list[BodySample] = []
    obstacles: list[BodySample] = []
    boxes: list = []
    gap = scene.particle_spacing
    for location, body in scene.bodies_with_location():
        count = (
            round(body.count.low)
            if body.count.is_fixed
            else int(rng.integers(int(body.count.low), int(body.count.high + 1)))
        )
        for copy in range(count):
            where = location if body.count.is_fixed and body.count.low == 1 else f"{location}[{copy}]"
            for _ in range(PLACEMENT_TRIES if scene.no_overlap else 1):
                sample = _sample_body(where, body, scene, rng)
                box = _box_of(sample)
                if not scene.no_overlap or _apart(box, boxes, gap):
                    break
            else:
                return None
            boxes.append(box)
            (blocks if isinstance(body, Block) else obstacles).append(sample)
    return blocks, obstacles


def sample_scene(scene: SceneSpec, seed: int) -> SceneSample:
    """Resolve every random value of ``scene`` with ``seed`` and fill its bodies with particles.

    Raises GnsError when ``no_overlap`` cannot place the bodies apart in the drawn domain.
    """
    check_scene(scene, f"scene {scene.name!r}")  # before any particle is allocated
    rng = np.random.default_rng(seed)
    drawn = draw_domain(scene, rng)
    for _ in range(SCENE_TRIES if scene.no_overlap else 1):
        bodies = _sample_bodies(drawn, rng)
        if bodies is not None:
            return SceneSample(*bodies, scene.property_names, drawn)
    raise GnsError(
        f"scene {scene.name!r}, seed {seed}: no_overlap could not place the bodies a particle spacing apart in "
        f"the drawn domain {drawn.domain.bounds} ({SCENE_TRIES} tries of {PLACEMENT_TRIES} per body): "
        "make the bodies smaller or fewer, or the domain larger"
    )


def at_resolution(sample: SceneSample, scene: SceneSpec, variant: SceneSpec, seed: int) -> SceneSample:
    """The same drawn scene at another resolution: its box, walls and bodies as drawn, refilled at the spacing of
    ``variant``'s grid and run with its time stepping.

    A reduced-resolution simulator is a yardstick only on the scene the data holds. Drawing
    the scene again at another grid would not give it: the draws after the first body's
    particles (jitter and per-particle properties, one number per particle) shift with the
    particle count, so columns, frictions and obstacles come out elsewhere. Here every body
    keeps its drawn box, angle, velocity, friction and per-body properties; only its
    particles are laid anew at the spacing of ``variant.domain.grid`` (cells along the
    longest axis of the bounds, as always), with fresh jitter, and a property drawn per particle is drawn
    again from the values the body had. The drawn box is rounded to whole cells of the new
    grid, as every domain is, so its walls move by less than half a new cell.

    Args:
        sample: the scene as drawn for the data (:func:`sample_scene` of ``scene`` and ``seed``).
        scene: the spec it was drawn from.
        variant: ``scene`` with another ``domain.grid`` (and ``time.substeps``, say).
        seed: the trajectory's seed (the new jitter is drawn from it and the grid).
    """
    assert sample.scene is not None  # sample_scene draws it
    domain, grid = sample.scene.domain, variant.domain.grid
    dx = max(hi - lo for lo, hi in scene.domain.bounds) / grid
    bounds = [(lo, lo + max(1, round((hi - lo) / dx)) * dx) for lo, hi in domain.bounds]
    resized = sample.scene.model_copy(
        update={
            "domain": domain.model_copy(update={"grid": grid, "bounds": bounds, "cell_size_override": dx}),
            "time": variant.time,
        }
    )
    specs = dict(scene.bodies_with_location())
    rng = np.random.default_rng([seed, grid])

    def refilled(body: BodySample) -> BodySample:
        spec = specs.get(body.location) or specs[body.location.rsplit("[", 1)[0]]
        position = _particles(spec, body.lower, body.size, body.angle, body.vertices, resized)
        if resized.jitter > 0 and isinstance(spec, Block):
            position = (
                position + rng.uniform(-resized.jitter, resized.jitter, position.shape) * resized.particle_spacing
            )
        values = {
            name: np.full(len(position), drawn[0]) if np.all(drawn == drawn[0]) else rng.choice(drawn, len(position))
            for name, drawn in body.values.items()
            if len(drawn)
        }
        return replace(body, position=position, values=values)

    return SceneSample(
        [refilled(b) for b in sample.blocks], [refilled(o) for o in sample.obstacles], sample.property_names, resized
    )
