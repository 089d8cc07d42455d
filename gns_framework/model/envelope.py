"""What a learned simulator was trained on, and the check that refuses data outside it.

A GNS learns the dynamics of the particles it saw: their spacing (the connectivity
radius is a few spacings), the time step (its accelerations are per step), their
materials and property values, how close to which walls they came, how fast they
moved. Outside that it extrapolates, and nothing in its output says so. Each
checkpoint therefore records its :class:`Envelope`, measured on the training
trajectories (as the model saw them, every ``frame_stride``-th frame), and every
command that rolls a model out checks its data against it first
(:func:`outside_envelope`): quantity by quantity, with the value found and the
range trained on.

Rollout length is not part of the envelope: a model runs as long as the data asks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import cast

import numpy as np

from ..contracts import ModelSetup
from ..data.metadata import DatasetMetadata
from ..data.particle_spacing import particle_spacing
from ..data.trajectory import Trajectory
from ..errors import GnsError
from ..ground_truth.scene_spec import FACES

SPACING_TOLERANCE = 0.10
"""Relative difference of particle spacing accepted: the lattice jitter of generated data moves it by a few %."""

DT_TOLERANCE = 1e-3
"""Relative difference of the learned step's duration accepted (rounding of stored time steps)."""

PROPERTY_SLACK = 0.02
"""Fraction of a trained property range (or of its value, for a single value) accepted beyond its ends."""


def property_slack(trained: list[float] | tuple[float, float]) -> float:
    """How far beyond either end of a ``trained`` (low, high) property range a value is accepted."""
    return PROPERTY_SLACK * max(trained[1] - trained[0], abs(trained[1]), 1e-12)


SPEED_SLACK = 1.25
"""Input speeds up to this multiple of the largest trained speed are accepted."""

COUNT_SLACK = (0.5, 1.5)
"""Particle counts accepted, as multiples of the smallest and largest trained count."""

WALL_SLACK = 0.01
"""Friction coefficients accepted beyond the ends of a trained wall-friction range."""


class OutsideEnvelope(GnsError):
    """Data outside what a model was trained on; ``problems`` lists each quantity."""

    def __init__(self, message: str, problems: list[str]):
        super().__init__(message)
        self.problems = problems


@dataclass(frozen=True)
class Envelope:
    """The training data's range, quantity by quantity (SI units when the data is in metres and seconds).

    Attributes:
        dim: spatial dimensions.
        particle_spacing: median nearest-neighbour distance among the moving (material) particles
            at frame 0, median over trajectories. Fixed obstacles and walls of particles have a
            lattice of their own (the rigid material is not jittered), so they are measured apart.
        step_dt: seconds per learned step (stored frame step x frame stride).
        frame_stride: stored frames per learned step.
        particle_types: type ids in the data.
        materials: material name of each type id (as registered when training).
        properties: material property name -> [lowest, highest] value of any moving particle.
        fixed_properties: the same of the fixed (kinematic) particles, which record a property where the scene
            says so (an obstacle's surface friction); None when the checkpoint predates it (then they are not
            judged).
        extent: per axis [smallest, largest] domain edge length.
        walls: per face (``x_min``, ...) ``{"friction": [low, high] of the rough faces or None,
            "slip": seen frictionless, "no_slip": seen no-slip}``; None when the data recorded no walls.
        max_speed: the largest particle speed between two consecutive (strided) frames, per second.
        particle_count: [fewest, most] particles in a trajectory.
        frames: (strided) frames per training trajectory, [fewest, most]; informational.
        boundary_spacing: [smallest, largest] median nearest-neighbour distance among the fixed
            (kinematic) particles of a trajectory, over the trajectories that have some; None
            when none has (or the checkpoint predates it: then they are not judged).
        refused_types: type id -> why data holding it is refused although the model was trained
            on it (what its evaluation measured there); set by ``scripts/refuse_types.py``.
    """

    dim: int
    particle_spacing: float
    step_dt: float
    frame_stride: int
    particle_types: list[int]
    materials: dict[str, str]
    properties: dict[str, list[float]]
    extent: list[list[float]]
    walls: dict[str, dict] | None
    max_speed: float
    particle_count: list[int]
    frames: list[int] = field(default_factory=list)
    boundary_spacing: list[float] | None = None
    refused_types: dict[str, str] = field(default_factory=dict)
    fixed_properties: dict[str, list[float]] | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict) -> Envelope:
        return cls(**raw)

    def union(self, earlier: Envelope) -> Envelope:
        """This envelope widened by ``earlier``'s ranges: a model fine-tuned on this data was trained on both.

        Materials, property ranges, extents, walls, speeds, counts and boundary spacings are joined. The
        particle spacing and learned step are this data's (the model is now fitted to
        them); a different dimension or frame stride is no model that was trained on both.
        Refusals are not kept: they were measured on the earlier model, not on this one.
        """
        if (earlier.dim, earlier.frame_stride) != (self.dim, self.frame_stride):
            raise ValueError(
                f"envelopes of {earlier.dim}D stride {earlier.frame_stride} and {self.dim}D stride "
                f"{self.frame_stride} cannot be joined"
            )

        def span(a: list, b: list) -> list:
            return [min(a[0], b[0]), max(a[1], b[1])]

        def joined(mine: dict[str, list[float]], theirs: dict[str, list[float]]) -> dict[str, list[float]]:
            out = dict(theirs)
            for name, values in mine.items():
                out[name] = span(out[name], values) if name in out else list(values)
            return out

        properties = joined(self.properties, earlier.properties)
        fixed = None
        if self.fixed_properties is not None and earlier.fixed_properties is not None:
            fixed = joined(self.fixed_properties, earlier.fixed_properties)
        walls = None
        if self.walls is not None or earlier.walls is not None:
            walls = {}
            for face in sorted(set(self.walls or {}) | set(earlier.walls or {})):
                mine, theirs = (self.walls or {}).get(face), (earlier.walls or {}).get(face)
                if mine is None or theirs is None:
                    walls[face] = dict(cast(dict, mine or theirs))  # a face of one of the two
                    continue
                frictions = [f for f in (mine["friction"], theirs["friction"]) if f is not None]
                walls[face] = {
                    "friction": span(frictions[0], frictions[-1]) if frictions else None,
                    "slip": bool(mine["slip"] or theirs["slip"]),
                    "no_slip": bool(mine["no_slip"] or theirs["no_slip"]),
                }
        return Envelope(
            dim=self.dim,
            particle_spacing=self.particle_spacing,
            step_dt=self.step_dt,
            frame_stride=self.frame_stride,
            particle_types=sorted(set(self.particle_types) | set(earlier.particle_types)),
            materials={**earlier.materials, **self.materials},
            properties=properties,
            fixed_properties=fixed,
            extent=[span(a, b) for a, b in zip(self.extent, earlier.extent, strict=True)],
            walls=walls,
            max_speed=max(self.max_speed, earlier.max_speed),
            particle_count=span(self.particle_count, earlier.particle_count),
            frames=span(self.frames, earlier.frames)
            if self.frames and earlier.frames
            else list(self.frames or earlier.frames),
            boundary_spacing=span(self.boundary_spacing, earlier.boundary_spacing)
            if self.boundary_spacing and earlier.boundary_spacing
            else self.boundary_spacing or earlier.boundary_spacing,
        )

    def rows(self) -> list[tuple[str, str]]:
        """(quantity, trained range) in words, for model cards and ``gns info``."""
        axes = "xyz"
        rows = [
            ("dimension", f"{self.dim}D"),
            ("nearest-neighbour distance (median)", f"{self.particle_spacing:.4g} m (+-{SPACING_TOLERANCE:.0%})"),
            (
                "learned step",
                f"{self.step_dt:.4g} s "
                f"({self.frame_stride} stored frame(s) of {self.step_dt / self.frame_stride:.4g} s)",
            ),
            (
                "materials",
                ", ".join(
                    f"{name} (type {t})" for t, name in sorted(self.materials.items(), key=lambda kv: int(kv[0]))
                ),
            ),
        ]
        if self.boundary_spacing:
            lo, hi = self.boundary_spacing
            rows.append(
                ("boundary nearest-neighbour distance (median)", f"{lo:.4g} .. {hi:.4g} m (+-{SPACING_TOLERANCE:.0%})")
            )
        rows += [
            (f"refused: {self.materials.get(t, '?')} (type {t})", reason) for t, reason in self.refused_types.items()
        ]
        rows += [(f"property {name}", f"{lo:.4g} .. {hi:.4g}") for name, (lo, hi) in self.properties.items()]
        rows += [
            (f"property {name} of fixed particles", f"{lo:.4g} .. {hi:.4g}")
            for name, (lo, hi) in (self.fixed_properties or {}).items()
        ]
        rows += [(f"domain {axes[a]} extent", f"{lo:.4g} .. {hi:.4g} m") for a, (lo, hi) in enumerate(self.extent)]
        rows += [(f"wall {face}", _wall_kinds(seen)) for face, seen in (self.walls or {}).items()]
        rows += [
            ("largest speed", f"{self.max_speed:.3g} m/s (inputs up to {SPEED_SLACK:g}x)"),
            ("particles per scene", f"{self.particle_count[0]} .. {self.particle_count[1]}"),
        ]
        return rows


def _wall_kinds(seen: dict) -> str:
    """What one face was trained with, in words: ``slip or friction 0.3 .. 0.6``."""
    kinds = (["slip"] if seen["slip"] else []) + (["no-slip"] if seen["no_slip"] else [])
    if seen["friction"] is not None:
        kinds.append(f"friction {seen['friction'][0]:.3g} .. {seen['friction'][1]:.3g}")
    return " or ".join(kinds)


def _spacings(position: np.ndarray, moving: np.ndarray) -> tuple[float, float | None]:
    """Particle spacing of the moving particles (of all, when fewer than two move) and of the fixed ones (None: fewer
    than two)."""
    material = particle_spacing(position[moving]) if moving.sum() >= 2 else particle_spacing(position)
    fixed = ~moving
    return material, (particle_spacing(position[fixed]) if fixed.sum() >= 2 else None)


def _property_values(trajectory: Trajectory, column: int, moving: np.ndarray) -> np.ndarray:
    """A property column of the moving particles (of all particles when none moves)."""
    assert trajectory.material_property is not None  # the callers check it
    values = trajectory.material_property[:, column]
    return values[moving] if moving.any() else values


def _spanned(ranges: dict[str, list[float]], name: str, values: np.ndarray) -> None:
    """Widen ``ranges[name]`` to hold ``values`` (none: unchanged)."""
    if values.size:
        low, high = float(values.min()), float(values.max())
        seen = ranges.setdefault(name, [low, high])
        seen[0], seen[1] = min(seen[0], low), max(seen[1], high)


def _extent(trajectory: Trajectory, metadata: DatasetMetadata) -> np.ndarray:
    """(d,) edge lengths of a trajectory's domain: its own bounds, else the dataset's."""
    bounds = np.asarray(trajectory.bounds if trajectory.bounds is not None else metadata.bounds, dtype=np.float64)
    return bounds[:, 1] - bounds[:, 0]


def _speed(position: np.ndarray, moving: np.ndarray, dt: float) -> float:
    """The largest speed of the ``moving`` particles between consecutive frames of (T, N, d) ``position``."""
    if position.shape[0] < 2 or not moving.any():
        return 0.0
    steps = np.linalg.norm(np.diff(position[:, moving], axis=0), axis=-1)
    return float(steps.max()) / dt


def measure_envelope(
    metadata: DatasetMetadata,
    trajectories: Sequence[Trajectory],
    scene: ModelSetup,
    materials: dict[int, str],
    frame_stride: int,
) -> Envelope:
    """The envelope of ``trajectories`` as the model sees them (already strided; ``metadata.dt`` is per learned
    step)."""
    spacings, boundary_spacings, counts, frames, speed = [], [], [], [], 0.0
    extents = []
    properties: dict[str, list[float]] = {}
    fixed_properties: dict[str, list[float]] = {}
    faces: dict[str, dict] | None = {}
    types: set[int] = set()
    kinematic = np.asarray(scene.kinematic_types, dtype=np.int64)
    for trajectory in trajectories:
        moving = ~np.isin(trajectory.particle_type, kinematic)
        material, boundary = _spacings(trajectory.position[0], moving)
        spacings.append(material)
        if boundary is not None:
            boundary_spacings.append(boundary)
        counts.append(trajectory.num_particles)
        frames.append(trajectory.num_steps)
        types.update(int(t) for t in np.unique(trajectory.particle_type))
        speed = max(speed, _speed(trajectory.position, moving, metadata.dt))
        extents.append(_extent(trajectory, metadata))
        if trajectory.material_property is not None:
            for column, name in enumerate(scene.property_names):
                _spanned(properties, name, _property_values(trajectory, column, moving))
                _spanned(fixed_properties, name, trajectory.material_property[~moving, column])
        if faces is not None:
            if trajectory.walls is None:
                faces = None
                continue
            for index, (friction, no_slip) in enumerate(np.asarray(trajectory.walls, dtype=np.float64)):
                face = faces.setdefault(FACES[index], {"friction": None, "slip": False, "no_slip": False})
                if no_slip:
                    face["no_slip"] = True
                elif friction == 0:
                    face["slip"] = True
                else:
                    low, high = face["friction"] or (friction, friction)
                    face["friction"] = [float(min(low, friction)), float(max(high, friction))]
    extents_array = np.asarray(extents)
    return Envelope(
        dim=metadata.dim,
        particle_spacing=float(np.median(spacings)),
        step_dt=float(metadata.dt),
        frame_stride=int(frame_stride),
        particle_types=sorted(types),
        materials={str(t): materials.get(t, "?") for t in sorted(types)},
        properties=properties,
        fixed_properties=fixed_properties,
        extent=[
            [float(lo), float(hi)] for lo, hi in zip(extents_array.min(axis=0), extents_array.max(axis=0), strict=True)
        ],
        walls=faces if faces else None,
        max_speed=speed,
        particle_count=[int(min(counts)), int(max(counts))],
        frames=[int(min(frames)), int(max(frames))],
        boundary_spacing=[float(min(boundary_spacings)), float(max(boundary_spacings))] if boundary_spacings else None,
    )


class _Findings:
    """Problems by quantity: the first trajectory and value, how many trajectories, the trained range."""

    def __init__(self):
        self.found: dict[str, dict] = {}

    def add(self, quantity: str, value: str, trained: str, key: str | None = None) -> None:
        entry = self.found.setdefault(quantity, {"value": value, "trained": trained, "keys": []})
        if key is not None:
            entry["keys"].append(key)

    def lines(self) -> list[str]:
        out = []
        for quantity, entry in self.found.items():
            keys = entry["keys"]
            where = ""
            if keys:
                where = f" in trajectory {keys[0]!r}" + (f" and {len(keys) - 1} more" if len(keys) > 1 else "")
            out.append(f"{quantity} {entry['value']}{where} (trained: {entry['trained']})")
        return out


def _within(value: float, low: float, high: float, slack: float) -> bool:
    return low - slack <= value <= high + slack


@dataclass(frozen=True)
class SceneMeasures:
    """What the envelope check reads of one scene's input, from a run of its particles: the runs of a scene split
    over processes (:mod:`gns_framework.data.in_parts`) merge into what the whole scene gives (:meth:`merged`).

    Attributes:
        key: the trajectory's key; ``particles``: its particle count (the whole scene's).
        spacing: particle spacing of frame 0's moving particles and of its fixed ones (None: fewer than two),
            measured on the whole frame by the run that starts at particle 0 (None on the others).
        types: particle types in the run; ``moving``: whether any of the run's particles moves.
        speed: largest input speed of the run's moving particles (m/s).
        properties: per material property column, (low, high) over the run's moving particles, over all of
            its particles (the scene's all count where none of the scene's particles moves) and over its fixed
            ones; None: no properties.
        lowest, highest: (d,) per axis, the moving particles' extremes over every frame (None: none moves).
        bounds: (d, 2) the domain's walls (its edge lengths are its extent); ``walls`` the face conditions.
    """

    key: str
    particles: int
    spacing: tuple[float, float | None] | None
    types: frozenset[int]
    moving: bool
    speed: float
    properties: tuple[tuple[tuple[float, float], tuple[float, float], tuple[float, float]], ...] | None
    lowest: tuple[float, ...] | None
    highest: tuple[float, ...] | None
    bounds: tuple[tuple[float, float], ...]
    walls: tuple[tuple[float, float], ...] | None

    def merged(self, other: SceneMeasures) -> SceneMeasures:
        """The measures of both runs' particles together (runs of the same scene)."""

        def extreme(pick, a, b):
            return b if a is None else a if b is None else tuple(pick(x, y) for x, y in zip(a, b, strict=True))

        def span(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
            return min(a[0], b[0]), max(a[1], b[1])

        properties = self.properties
        if self.properties is not None and other.properties is not None:
            # A run without moving particles has the empty range (inf, -inf), which a span absorbs.
            pairs = zip(self.properties, other.properties, strict=True)
            properties = tuple((span(a[0], b[0]), span(a[1], b[1]), span(a[2], b[2])) for a, b in pairs)
        return replace(
            self,
            spacing=self.spacing if self.spacing is not None else other.spacing,
            types=self.types | other.types,
            moving=self.moving or other.moving,
            speed=max(self.speed, other.speed),
            properties=properties,
            lowest=extreme(min, self.lowest, other.lowest),
            highest=extreme(max, self.highest, other.highest),
        )


def scene_measures(
    trajectory: Trajectory,
    metadata: DatasetMetadata,
    history: int,
    kinematic_types: Sequence[int] = (),
    rows: slice | None = None,
) -> SceneMeasures:
    """The envelope check's measures of ``trajectory``'s particles ``rows`` (default: all); positions the scene
    left unchecked are checked on them (:meth:`~gns_framework.data.trajectory.Trajectory.particles`). Only the
    input, the first ``history`` frames, counts for speed; every frame for the walls the particles come near."""
    kinematic = np.asarray(list(kinematic_types), dtype=np.int64)
    run = trajectory.particles(rows if rows is not None else slice(None))
    moving = ~np.isin(run.particle_type, kinematic)
    spacing = None
    if rows is None or rows.start in (None, 0):
        frame = np.asarray(trajectory.position[0])
        spacing = _spacings(frame, ~np.isin(trajectory.particle_type, kinematic))
    properties = None
    if run.material_property is not None:
        columns = np.asarray(run.material_property, dtype=np.float64)
        properties = tuple(
            (_range(columns[moving, k]), _range(columns[:, k]), _range(columns[~moving, k]))
            for k in range(columns.shape[1])
        )
    lowest = highest = None
    if moving.any():
        low, high = [], []
        for first in range(0, run.num_steps, 64):  # in chunks of frames: a mapped run is never copied whole
            frames = np.asarray(run.position[first : first + 64])[:, moving]
            low.append(frames.min(axis=(0, 1)))
            high.append(frames.max(axis=(0, 1)))
        lowest, highest = tuple(np.min(low, axis=0).tolist()), tuple(np.max(high, axis=0).tolist())
    bounds = np.asarray(trajectory.bounds if trajectory.bounds is not None else metadata.bounds, dtype=np.float64)
    return SceneMeasures(
        key=trajectory.key,
        particles=trajectory.num_particles,
        spacing=spacing,
        types=frozenset(int(t) for t in np.unique(run.particle_type)),
        moving=bool(moving.any()),
        speed=_speed(np.asarray(run.position[:history]), moving, metadata.dt),
        properties=properties,
        lowest=lowest,
        highest=highest,
        bounds=tuple((float(lo), float(hi)) for lo, hi in bounds),
        walls=None
        if trajectory.walls is None
        else tuple(map(tuple, np.asarray(trajectory.walls, np.float64).tolist())),
    )


def _range(values: np.ndarray) -> tuple[float, float]:
    """(low, high) of ``values``; (inf, -inf) when there are none, which any span absorbs."""
    return (float(values.min()), float(values.max())) if values.size else (math.inf, -math.inf)


def outside_envelope(
    envelope: Envelope,
    metadata: DatasetMetadata,
    trajectories: Sequence[Trajectory],
    history: int,
    kinematic_types: Sequence[int] = (),
) -> list[str]:
    """What in the data lies outside ``envelope``, one line per quantity (empty: all inside).

    ``trajectories`` are seen as the model will see them (strided). Only a rollout's
    inputs are judged (its first ``history`` frames, the speeds among them): the
    frames after them are what the model is asked to predict.
    """
    if metadata.dim != envelope.dim:
        return [f"dimension {metadata.dim}D (trained: {envelope.dim}D)"]
    measures = [scene_measures(t, metadata, history, kinematic_types) for t in trajectories]
    return outside_envelope_of(envelope, metadata, measures)


def outside_envelope_of(envelope: Envelope, metadata: DatasetMetadata, scenes: Sequence[SceneMeasures]) -> list[str]:
    """:func:`outside_envelope` of scenes already measured (:func:`scene_measures`, runs merged)."""
    findings = _Findings()
    if metadata.dim != envelope.dim:
        findings.add("dimension", f"{metadata.dim}D", f"{envelope.dim}D")
        return findings.lines()
    if not math.isclose(metadata.dt, envelope.step_dt, rel_tol=DT_TOLERANCE):
        findings.add("learned step", f"{metadata.dt:.4g} s", f"{envelope.step_dt:.4g} s")
    trained_types = set(envelope.particle_types)
    axes = "xyz"
    for scene in scenes:
        key = scene.key
        assert scene.spacing is not None, "the run that starts at particle 0 measures the spacing"
        spacing, boundary = scene.spacing
        if abs(spacing / envelope.particle_spacing - 1) > SPACING_TOLERANCE:
            findings.add(
                "nearest-neighbour distance (median)",
                f"{spacing:.4g} m",
                f"{envelope.particle_spacing:.4g} m +-{SPACING_TOLERANCE:.0%}",
                key,
            )
        if envelope.boundary_spacing and boundary is not None:
            lo, hi = envelope.boundary_spacing
            if not lo * (1 - SPACING_TOLERANCE) <= boundary <= hi * (1 + SPACING_TOLERANCE):
                findings.add(
                    "boundary nearest-neighbour distance (median)",
                    f"{boundary:.4g} m",
                    f"{lo:.4g} .. {hi:.4g} m +-{SPACING_TOLERANCE:.0%}",
                    key,
                )
        unknown = sorted(scene.types - trained_types)
        if unknown:
            findings.add("particle types", f"{unknown}", f"{envelope.particle_types}", key)
        for refused, reason in envelope.refused_types.items():
            if int(refused) in scene.types:
                material = envelope.materials.get(refused, "?")
                findings.add(
                    f"{material} particles (type {refused})", "present", f"on them, but refused: {reason}", key
                )
        low, high = envelope.particle_count
        if not COUNT_SLACK[0] * low <= scene.particles <= COUNT_SLACK[1] * high:
            findings.add(
                "particle count",
                f"{scene.particles}",
                f"{low} .. {high}, accepted {COUNT_SLACK[0]:g}x .. {COUNT_SLACK[1]:g}x",
                key,
            )
        if scene.speed > SPEED_SLACK * envelope.max_speed:
            findings.add(
                "input speed",
                f"{scene.speed:.3g} m/s",
                f"up to {envelope.max_speed:.3g} m/s, accepted {SPEED_SLACK:g}x",
                key,
            )
        bounds = np.asarray(scene.bounds, dtype=np.float64)
        for axis, (value, (lo, hi)) in enumerate(zip(bounds[:, 1] - bounds[:, 0], envelope.extent, strict=True)):
            if not _within(value, lo, hi, 2 * envelope.particle_spacing):
                findings.add(f"domain {axes[axis]} extent", f"{value:.4g} m", f"{lo:.4g} .. {hi:.4g} m", key)
        if scene.properties is not None:
            # The columns both the data and the envelope have: a missing column has no values to judge.
            pairs = zip(envelope.properties.items(), scene.properties, strict=False)
            for (name, trained), (of_moving, of_all, _) in pairs:
                _judge_property(findings, f"property {name}", of_moving if scene.moving else of_all, trained, key)
            if envelope.fixed_properties is not None:
                # A fixed particle's property (an obstacle's friction) is an input like any other: judged by the
                # column's name against what the fixed particles had when trained (absent: never recorded, 0).
                for (name, _), (_, _, of_fixed) in zip(envelope.properties.items(), scene.properties, strict=False):
                    trained = envelope.fixed_properties.get(name, [0.0, 0.0])
                    _judge_property(findings, f"property {name} of fixed particles", of_fixed, trained, key)
        if envelope.walls is not None and scene.walls is not None:
            reached = _faces_reached(scene, REACH_SPACINGS * envelope.particle_spacing)
            for index, (friction, no_slip) in enumerate(scene.walls):
                face = FACES[index]
                seen = envelope.walls.get(face)
                if seen is None or not reached[index]:
                    continue  # a face the material never comes near (the top of a collapse) is not the model's to know
                if no_slip:
                    ok, value = seen["no_slip"], "no-slip"
                elif friction == 0:
                    ok, value = seen["slip"], "slip"
                else:
                    ok = seen["friction"] is not None and _within(
                        friction, *cast("tuple[float, float]", seen["friction"]), WALL_SLACK
                    )
                    value = f"friction {friction:.3g}"
                if not ok:
                    findings.add(f"wall {face}", value, _wall_kinds(seen), key)
    return findings.lines()


def _judge_property(
    findings: _Findings, quantity: str, values: tuple[float, float], trained: list[float], key: str
) -> None:
    """Add ``values`` (low, high; (inf, -inf): none) to ``findings`` where they leave the ``trained`` range."""
    lo, hi = trained
    slack = property_slack(trained)
    if values[0] < lo - slack:
        findings.add(quantity, f"{values[0]:.4g}", f"{lo:.4g} .. {hi:.4g}", key)
    elif values[1] > hi + slack:
        findings.add(quantity, f"{values[1]:.4g}", f"{lo:.4g} .. {hi:.4g}", key)


REACH_SPACINGS = 4
"""A face is judged when a moving particle comes within this many particle spacings of it at any frame."""


def _faces_reached(scene: SceneMeasures, reach: float) -> list[bool]:
    """Per face (``FACES`` order), whether a moving particle comes within ``reach`` of it in any frame."""
    if scene.lowest is None or scene.highest is None:
        return [False] * (2 * len(scene.bounds))
    reached = []
    for (lower, upper), lowest, highest in zip(scene.bounds, scene.lowest, scene.highest, strict=True):
        reached += [lowest <= lower + reach, highest >= upper - reach]
    return reached


def envelope_message(source: str, model: str, problems: list[str]) -> str:
    """The refusal: the data, the model, each quantity outside, and the way to run anyway."""
    listed = "".join(f"\n  - {line}" for line in problems)
    return (
        f"{source}: outside the envelope of {model}, which extrapolates there without knowing it:{listed}\n"
        "Pass --outside-envelope to roll out anyway; the warning is then recorded in every output."
    )
