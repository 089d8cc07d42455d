"""Draw one concrete scene from a spec: random ranges resolved, bodies filled with particles.

Any ground-truth simulator can start from this; the draws depend only on the
spec and the seed, in a fixed order, so a seed always gives the same particles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..contracts import Material
from . import shapes
from .scene_spec import Block, Obstacle, Range, SceneSpec


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
            the spec sets for this body.
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
    """A drawn scene: blocks' particles first, then obstacles' (kinematic) particles."""

    blocks: list[BodySample]
    obstacles: list[BodySample]
    property_names: tuple[str, ...]

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


def _draw(value: Range, rng: np.random.Generator, count: int) -> np.ndarray:
    """(count,) draws; one shared draw unless the range is per particle."""
    if value.is_fixed:
        return np.full(count, value.low)
    if value.per == "particle":
        return rng.uniform(value.low, value.high, size=count)
    return np.full(count, rng.uniform(value.low, value.high))


def _draw_vector(values: list[Range] | None, rng: np.random.Generator, dim: int) -> np.ndarray:
    if values is None:
        return np.zeros(dim)
    return np.array([_draw(v, rng, 1)[0] for v in values])


def fill(shape: str, lower: np.ndarray, size: np.ndarray, spacing: float) -> np.ndarray:
    """(n, d) lattice points at ``spacing`` inside a box or its inscribed ellipsoid.

    Points sit at cell centres of a lattice anchored at ``lower``, so each
    particle stands for a volume ``spacing ** d``.
    """
    counts = [max(1, int(round(s / spacing))) for s in size]
    axes = [lower[a] + (np.arange(n) + 0.5) * spacing for a, n in enumerate(counts)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(size))
    if shape == "ellipsoid":
        centre, radii = lower + size / 2, size / 2
        points = points[(((points - centre) / radii) ** 2).sum(axis=1) <= 1.0]
    return points


def _particles(
    body: Block | Obstacle, lower: np.ndarray, size: np.ndarray, angle: float, vertices: np.ndarray | None,
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
        points = shapes.polygon_lattice(vertices, spacing)
    else:
        points = shapes.rotate_xy(fill(body.shape, lower, size, spacing), angle, lower + size / 2)
    if isinstance(body, Obstacle) and body.is_static_shape:
        points = points[shapes.inside(points, bounds)]
    return points


def _sample_body(
    location: str, body: Block | Obstacle, scene: SceneSpec, rng: np.random.Generator
) -> BodySample:
    d = scene.dim
    lower = _draw_vector(body.position, rng, d)
    size = _draw_vector(body.size, rng, d)
    velocity = _draw_vector(body.velocity, rng, d)
    angle = float(_draw(body.angle, rng, 1)[0])
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
    return BodySample(
        location, body.material, body.shape, lower, size, velocity, position, values, friction, angle, vertices
    )


def sample_scene(scene: SceneSpec, seed: int) -> SceneSample:
    """Resolve every random range of ``scene`` with ``seed`` and fill its bodies with particles."""
    rng = np.random.default_rng(seed)
    blocks = [_sample_body(f"blocks[{i}]", b, scene, rng) for i, b in enumerate(scene.blocks)]
    obstacles = [_sample_body(f"obstacles[{i}]", o, scene, rng) for i, o in enumerate(scene.obstacles)]
    return SceneSample(blocks, obstacles, scene.property_names)
