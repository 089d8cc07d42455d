"""The values ``gns generate`` drew for each trajectory, recorded beside the dataset (``drawn.json``).

A scene's ranges are drawn anew for every trajectory (sampling.py): a block's position,
size, launch velocity and angle, its per-trajectory properties, an obstacle's surface
friction, the domain's extent and wall conditions. The trajectory files hold only the
particles; ``drawn.json`` keeps what was drawn, so that an answer found from the data
(``gns invert``) can be checked against the truth::

    {"format": 1,
     "trajectories": {
       "seed_3451799802": {
         "domain":    {"bounds": [[0, 1], [0, 0.6]], "extent": [1, 0.6],
                       "walls": {"x_min": {"friction": 0.5, "no_slip": false}, ...}},
         "blocks[0]": {"material": "sand", "particle_type": 6, "shape": "box",
                       "position": [0.12, 0.2], "size": [0.1, 0.08], "velocity": [0.57, 0.09],
                       "angle": 0.0, "friction": 0.7},
         "obstacles[0]": {..., "friction": 0.3}}}}

Positions are the bounding box's lower corner before rotation, metres; velocities m/s;
angles degrees. A property drawn per particle is recorded by its mean, min and max
(``{"mean": ..., "min": ..., "max": ...}``); one drawn per body is a number.

A dataset generated before this file existed is read from its metadata's
``generated_from`` scene instead: the draws depend only on the scene and the seed in
the trajectory's key (``seed_<n>``), so they are drawn again (:func:`read_drawn`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..contracts import Material
from ..data.atomic import write_text_atomic
from .sampling import BodySample, SceneSample, sample_scene
from .scene_spec import FACES, SceneSpec

DRAWN_FILE = "drawn.json"
FORMAT = 1


def _value(array: np.ndarray) -> float | dict:
    array = np.asarray(array, dtype=np.float64)
    if array.size and np.all(array == array.flat[0]):
        return float(array.flat[0])
    if not array.size:
        return float("nan")
    return {"mean": float(array.mean()), "min": float(array.min()), "max": float(array.max())}


def _body(body: BodySample, materials: Mapping[str, type[Material]], obstacle: bool) -> dict:
    record: dict = {"material": body.material, "shape": body.shape}
    if body.material in materials:
        record["particle_type"] = int(materials[body.material].particle_type)
    record.update(
        position=[float(v) for v in body.lower],
        size=[float(v) for v in body.size],
        velocity=[float(v) for v in body.velocity],
        angle=float(body.angle),
        particles=body.num_particles,
    )
    if body.vertices is not None:
        record["vertices"] = np.asarray(body.vertices, dtype=np.float64).tolist()
    if obstacle:
        record["friction"] = float(body.friction)
    for name, values in body.values.items():
        record[name] = _value(values)
    return record


def drawn_record(sample: SceneSample, materials: Mapping[str, type[Material]]) -> dict:
    """``{location: {field: value}}`` of one drawn scene: its domain, every block and obstacle."""
    scene = sample.scene
    assert scene is not None  # sample_scene draws it
    walls = scene.domain.wall_conditions()
    faces = FACES[: 2 * scene.dim]
    record: dict = {
        "domain": {
            "bounds": [[float(lo), float(hi)] for lo, hi in scene.domain.bounds],
            "extent": [float(hi - lo) for lo, hi in scene.domain.bounds],
            "walls": {
                face: {"friction": float(f), "no_slip": bool(n)} for face, (f, n) in zip(faces, walls, strict=True)
            },
        }
    }
    for body in sample.blocks:
        record[body.location] = _body(body, materials, obstacle=False)
    for body in sample.obstacles:
        record[body.location] = _body(body, materials, obstacle=True)
    return record


def write_drawn(
    out: Path, scene: SceneSpec, keyed_seeds: Iterable[tuple[str, int]], materials: Mapping[str, type[Material]]
) -> Path:
    """``out/drawn.json`` (atomically) for the trajectories ``(key, seed)`` of ``scene``."""
    trajectories = {key: drawn_record(sample_scene(scene, seed), materials) for key, seed in keyed_seeds}
    path = Path(out) / DRAWN_FILE
    write_text_atomic(
        path, json.dumps({"format": FORMAT, "scene": scene.name, "trajectories": trajectories}, indent=1) + "\n"
    )
    return path


def read_drawn(folder: str | Path, key: str, materials: Mapping[str, type[Material]] | None = None) -> dict | None:
    """What was drawn for trajectory ``key`` of the dataset in ``folder``; None when nothing tells.

    From ``drawn.json``, else drawn again from ``metadata.json``'s ``generated_from``
    scene and the seed in the key (datasets generated before ``drawn.json``).
    """
    folder = Path(folder)
    try:
        recorded = json.loads((folder / DRAWN_FILE).read_text())
        return recorded["trajectories"].get(key)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    if not key.startswith("seed_") or not key.removeprefix("seed_").isdigit():
        return None
    try:
        metadata = json.loads((folder / "metadata.json").read_text())
        scene = SceneSpec.model_validate(metadata["generated_from"]["scene"])
    except Exception:  # any unreadable or outdated provenance: the truth is unknown
        return None
    if materials is None:
        from ..plugins import load_registry

        registry = load_registry()
        materials = {name: registry.get("material", name) for name in registry.names("material")}
    return drawn_record(sample_scene(scene, int(key.removeprefix("seed_"))), materials)


def _blocks(record: Mapping, particle_type: int | None) -> list[dict]:
    return [
        body
        for location, body in record.items()
        if location.startswith("blocks") and (particle_type is None or body.get("particle_type") == particle_type)
    ]


def true_velocity(record: Mapping, particle_type: int) -> list[float] | None:
    """The launch velocity shared by every block of ``particle_type``; None if they differ or there is none."""
    velocities = {tuple(body["velocity"]) for body in _blocks(record, particle_type)}
    return list(velocities.pop()) if len(velocities) == 1 else None


def true_property(record: Mapping, name: str, particle_type: int | None) -> float | None:
    """The value of property ``name`` shared by the blocks concerned (every block if no type); None otherwise."""
    values: set[Any] = {
        body.get(name) if not isinstance(body.get(name), dict) else None for body in _blocks(record, particle_type)
    }
    return float(values.pop()) if len(values) == 1 and None not in values else None
