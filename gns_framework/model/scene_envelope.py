"""A scene file checked against what a model was trained on, before any data is generated (``gns envelope``).

The data check (:func:`~gns_framework.model.envelope.outside_envelope`) judges particles
once they exist; a user writing a scene wants the answer in the scene file's own terms
first: which ``domain.grid`` gives the model's particle spacing, which frame step its
learned step needs, whether a column of 0.7 m is taller than any it saw. Each finding
names the scene field, the value asked for and what the model was trained on (the
training scene, recorded in the checkpoint's metadata by ``gns generate``, and the
envelope measured on the training data).

Shapes are not judged beyond their boxes and counts; a top face the sand cannot reach
(no block launched upwards, the box higher than every block) is not judged at all.
"""

from __future__ import annotations

import math

from ..ground_truth.scene_spec import FACES, Block, Obstacle, OneOf, Range, SceneSpec, Span, WallChoice, WallRange
from ..limits import scene_particles
from .envelope import (
    COUNT_SLACK,
    DT_TOLERANCE,
    REACH_SPACINGS,
    SPACING_TOLERANCE,
    WALL_SLACK,
    Envelope,
    property_slack,
)


def value_range(value) -> tuple[float, float] | None:
    """(lowest, highest) a scene value can take; None for a span (a place relative to the box, not a length)."""
    if isinstance(value, (int, float)):
        return float(value), float(value)
    if isinstance(value, Range):
        return value.low, value.high
    if isinstance(value, Span):
        return None
    if isinstance(value, OneOf):
        ranges = [r for r in (value_range(option) for option in value.one_of) if r is not None]
        return (min(r[0] for r in ranges), max(r[1] for r in ranges)) if ranges else None
    return None


def _face_kinds(condition, default: float) -> list[tuple[str, float]]:
    """A face's possible conditions as (kind, friction): ``slip``, ``no_slip`` or ``friction`` with its value(s)."""
    if condition is None:
        condition = default
    if isinstance(condition, WallChoice):
        return [kind for option in condition.one_of for kind in _face_kinds(option, default)]
    if isinstance(condition, WallRange):
        return [("friction", condition.range[0]), ("friction", condition.range[1])]
    if condition == "no_slip":
        return [("no_slip", 0.0)]
    if condition == "slip" or condition == 0:
        return [("slip", 0.0)]
    return [("friction", float(condition))]


def _box_extents(scene: SceneSpec) -> list[tuple[float, float]]:
    """(smallest, largest) edge length of the scene's box per axis."""
    if scene.domain.extent is None:
        return [(hi - lo, hi - lo) for lo, hi in scene.domain.bounds]
    return [_length_range(e) for e in scene.domain.extent]


def _length_range(value) -> tuple[float, float]:
    found = value_range(value)
    assert found is not None  # extents are lengths, never spans (SceneSpec checks it)
    return found


def _top_reachable(scene: SceneSpec) -> bool:
    """Whether a block may come near the box's top face: launched upwards, or its top near the lowest box top."""
    lowest_top = scene.domain.bounds[1][0] + _box_extents(scene)[1][0]
    for block in scene.blocks:
        velocity = value_range(block.velocity[1]) if block.velocity else (0.0, 0.0)
        if velocity is None or velocity[1] > 0:
            return True
        start, size = value_range(block.position[1]), value_range(block.size[1])
        top = (start[1] if start else scene.domain.bounds[1][1]) + (size[1] if size else 0.0)
        if top + REACH_SPACINGS * scene.particle_spacing >= lowest_top:
            return True
    return False


def _block_sizes(scene: SceneSpec, material: str) -> list[tuple[float, float]] | None:
    """Per axis (smallest, largest) size of the scene's blocks of ``material``; None when it has none."""
    found = None
    for block in scene.blocks:
        if block.material != material:
            continue
        sizes = [value_range(v) or (0.0, math.inf) for v in block.size]
        found = (
            sizes if found is None else [(min(a[0], b[0]), max(a[1], b[1])) for a, b in zip(found, sizes, strict=True)]
        )
    return found


def scene_problems(scene: SceneSpec, envelope: Envelope, trained: SceneSpec | None) -> list[tuple[str, str]]:
    """(scene field, what is outside and what was trained) for everything of ``scene`` outside the model's training.

    ``trained``: the scene the training data was generated from (None when the data came from
    elsewhere: only the envelope's measured quantities are judged then).
    """
    problems: list[tuple[str, str]] = []
    axes = "xyz"
    if scene.dim != envelope.dim:
        return [("dim", f"{scene.dim}D; the model is {envelope.dim}D")]
    step = scene.time.frame_dt * envelope.frame_stride
    if not math.isclose(step, envelope.step_dt, rel_tol=DT_TOLERANCE):
        problems.append(
            (
                "time.frame_dt",
                f"{scene.time.frame_dt:.4g} s makes a learned step of {step:.4g} s ({envelope.frame_stride} frames); "
                f"the model steps {envelope.step_dt:.4g} s: frame_dt {envelope.step_dt / envelope.frame_stride:.4g} s",
            )
        )
    if trained is not None:
        lattice, want = scene.particle_spacing, trained.particle_spacing
        if abs(lattice / want - 1) > SPACING_TOLERANCE:
            longest = max(hi - lo for lo, hi in scene.domain.bounds)
            grid = round(longest / (want * scene.particles_per_cell))
            problems.append(
                (
                    "domain.grid",
                    f"{scene.domain.grid} cells over {longest:.4g} m with particles_per_cell "
                    f"{scene.particles_per_cell} "
                    f"lay particles {lattice:.4g} m apart; the model was trained at {want:.4g} m: domain.grid {grid}",
                )
            )
    for axis, ((low, high), (trained_low, trained_high)) in enumerate(
        zip(_box_extents(scene), envelope.extent, strict=True)
    ):
        slack = 2 * envelope.particle_spacing
        if low < trained_low - slack or high > trained_high + slack:
            asked = f"{low:.4g} m" if low == high else f"{low:.4g} .. {high:.4g} m"
            problems.append(
                (
                    f"domain.{'extent' if scene.domain.extent else 'bounds'}[{axis}]",
                    f"the box is {asked} along {axes[axis]}; trained {trained_low:.4g} .. {trained_high:.4g} m",
                )
            )
    problems += _wall_problems(scene, envelope)
    problems += _body_problems(scene, envelope, trained)
    most, _ = scene_particles(scene)
    # With the training scene known, its box, blocks and counts are judged above and bound the particle count;
    # an upper bound of the count alone would refuse the training scene itself (no_overlap keeps it lower).
    if trained is None and most > COUNT_SLACK[1] * envelope.particle_count[1]:
        problems.append(
            (
                "blocks",
                f"up to about {most:,.0f} particles per scene; trained {envelope.particle_count[0]:,} .. "
                f"{envelope.particle_count[1]:,} (accepted up to {COUNT_SLACK[1]:g}x)",
            )
        )
    return problems


def _wall_problems(scene: SceneSpec, envelope: Envelope) -> list[tuple[str, str]]:
    if envelope.walls is None:
        return []
    problems = []
    # The top face (y_max, the last face of a 2D box) is left out when no block can reach it.
    skip_top = scene.dim == 2 and not _top_reachable(scene)
    for face in FACES[: 2 * scene.dim]:
        seen = envelope.walls.get(face)
        if seen is None or (face == "y_max" and skip_top):
            continue
        for kind, friction in _face_kinds(getattr(scene.domain.walls, face), scene.domain.wall_friction):
            if kind == "friction":
                rough = seen["friction"]
                ok = rough is not None and rough[0] - WALL_SLACK <= friction <= rough[1] + WALL_SLACK
                asked = f"friction {friction:.3g}"
            else:
                ok, asked = bool(seen[kind]), kind.replace("_", "-")
            if not ok:
                problems.append((f"domain.walls.{face}", f"{asked}; trained {_trained_face(seen)}"))
                break
    return problems


def _trained_face(seen: dict) -> str:
    kinds = [k.replace("_", "-") for k in ("slip", "no_slip") if seen[k]]
    if seen["friction"] is not None:
        kinds.append(f"friction {seen['friction'][0]:.3g} .. {seen['friction'][1]:.3g}")
    return " or ".join(kinds) or "nothing"


def _body_problems(scene: SceneSpec, envelope: Envelope, trained: SceneSpec | None) -> list[tuple[str, str]]:
    problems = []
    materials = set(envelope.materials.values())
    for location, body in scene.bodies_with_location():
        if body.material not in materials:
            problems.append((f"{location}.material", f"{body.material!r}; trained on {', '.join(sorted(materials))}"))
            continue
        if not isinstance(body, Block):
            problems += _obstacle_friction_problems(location, body, envelope)
            continue
        for name, value in body.properties.items():
            asked, known = value_range(value), envelope.properties.get(name)
            if asked is None or known is None:
                continue
            slack = property_slack(known)
            if asked[0] < known[0] - slack or asked[1] > known[1] + slack:
                problems.append(
                    (
                        f"{location}.properties.{name}",
                        f"{_shown(asked)}; trained {known[0]:.4g} .. {known[1]:.4g}",
                    )
                )
        sizes = _block_sizes(trained, body.material) if trained is not None else None
        if sizes is None:
            continue
        slack = 2 * envelope.particle_spacing
        for axis, (value, (low, high)) in enumerate(zip(body.size, sizes, strict=True)):
            asked = value_range(value)
            if asked is not None and (asked[0] < low - slack or asked[1] > high + slack):
                problems.append(
                    (
                        f"{location}.size[{axis}]",
                        f"{_shown(asked)} m along {'xyz'[axis]}; trained {body.material} blocks {low:.4g} .. "
                        f"{high:.4g} m",
                    )
                )
    if trained is not None:
        asked_blocks = float(sum(b.count.high for b in scene.blocks))
        trained_blocks = float(sum(b.count.high for b in trained.blocks))
        if asked_blocks > trained_blocks:
            problems.append(("blocks", f"up to {asked_blocks:g} blocks per scene; trained up to {trained_blocks:g}"))
    return problems


def _obstacle_friction_problems(location: str, obstacle: Obstacle, envelope: Envelope) -> list[tuple[str, str]]:
    """An obstacle's surface friction where the model's fixed particles had a recorded friction: the scene's must be
    recorded (else its particles read 0) and lie in the trained range. Not judged for checkpoints that predate it."""
    known = (envelope.fixed_properties or {}).get("friction")
    if known is None:
        return []
    asked = value_range(obstacle.friction) if obstacle.record_friction else (0.0, 0.0)
    if asked is None:
        return []
    slack = property_slack(known)
    if known[0] - slack <= asked[0] and asked[1] <= known[1] + slack:
        return []
    recorded = "" if obstacle.record_friction else " (not recorded: its particles read 0; record_friction: true)"
    return [(f"{location}.friction", f"{_shown(asked)}{recorded}; trained {known[0]:.4g} .. {known[1]:.4g}")]


def _shown(span: tuple[float, float]) -> str:
    return f"{span[0]:.4g}" if span[0] == span[1] else f"{span[0]:.4g} .. {span[1]:.4g}"


def scene_file_terms(trained: SceneSpec | None, envelope: Envelope) -> list[str]:
    """The envelope as a scene file says it: lattice, box, walls, blocks, obstacles, then what was measured."""
    lines = []
    if trained is not None:
        domain = trained.domain
        longest = max(hi - lo for lo, hi in domain.bounds)
        lines += [
            f"scene: {trained.name} ({trained.dim}D)",
            f"lattice: domain.grid {domain.grid} over the largest box ({longest:.4g} m, dx {domain.cell_size:.4g} m), "
            f"particles_per_cell {trained.particles_per_cell}: particles {trained.particle_spacing:.4g} m apart "
            f"(jitter {trained.jitter:g}); for a box of L m use domain.grid = L / {domain.cell_size:.4g}",
            f"time: frame_dt {trained.time.frame_dt:g} s x frame_stride {envelope.frame_stride} = learned step "
            f"{envelope.step_dt:.4g} s; {trained.time.frames} frames "
            f"({trained.time.frames * trained.time.frame_dt:.3g} s)",
        ]
    for axis, (low, high) in enumerate(envelope.extent):
        lines.append(f"box {'xyz'[axis]}: {low:.4g} .. {high:.4g} m")
    for face, seen in (envelope.walls or {}).items():
        lines.append(f"wall {face}: {_trained_face(seen)}")
    if trained is not None:
        for location, body in trained.bodies_with_location():
            count = value_range(body.count) or (0, 0)
            sizes = " x ".join(_shown(value_range(v) or (0, 0)) for v in (body.size or []))
            extra = "".join(
                f", {name} {_shown(r)}" for name, v in getattr(body, "properties", {}).items() if (r := value_range(v))
            )
            if isinstance(body, Obstacle) and body.record_friction and (r := value_range(body.friction)):
                extra += f", friction {_shown(r)} (recorded)"
            lines.append(f"{location}: {_shown(count)} {body.material} {body.shape}(s) of {sizes or '-'} m{extra}")
    lines += [
        f"measured on the training data: median nearest-neighbour distance {envelope.particle_spacing:.4g} m, "
        f"{envelope.particle_count[0]:,} .. {envelope.particle_count[1]:,} particles per scene, "
        f"largest speed {envelope.max_speed:.3g} m/s",
    ]
    lines += [f"property {name}: {low:.4g} .. {high:.4g}" for name, (low, high) in envelope.properties.items()]
    lines += [
        f"property {name} of fixed particles: {low:.4g} .. {high:.4g}"
        for name, (low, high) in (envelope.fixed_properties or {}).items()
    ]
    return lines
