"""Deriving the scene (what the model must handle) from dataset metadata, data and recipe."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np

from ..config.recipe import ModelSpec
from ..contracts import ModelSetup
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..errors import DatasetError, RecipeError
from ..plugins import Registry


class _Seen(NamedTuple):
    """What the scene needs of one trajectory: read once, kept small."""

    key: str
    types: frozenset[int]
    properties: int
    """material_property columns (0: none)."""
    context: int
    """step_context width (0: none)."""
    walls: np.ndarray | None

    @classmethod
    def of(cls, trajectory: Trajectory) -> _Seen:
        prop, ctx = trajectory.material_property, trajectory.step_context
        return cls(
            trajectory.key,
            frozenset(int(t) for t in np.unique(trajectory.particle_type)),
            0 if prop is None else prop.shape[1],
            0 if ctx is None else ctx.shape[1],
            trajectory.walls,
        )


def scene_from_data(
    metadata: DatasetMetadata,
    trajectories: Iterable[Trajectory],
    model: ModelSpec,
    registry: Registry,
    source: str = "dataset",
) -> ModelSetup:
    """Build the scene a model is sized for.

    Materials: the recipe's ``model.materials`` or, by default, those whose particle
    types occur in ``trajectories``. Properties and context exist only when the data
    carries them, so a scene never pays for features it does not use.

    The trajectories are read once, one at a time: a split that keeps few of them in
    memory (``dataset.memory: windows``) is never held whole.
    """
    seen = [_Seen.of(traj) for traj in trajectories]
    if model.materials:
        materials = [registry.get("material", name) for name in model.materials]
    else:
        present = sorted({t for summary in seen for t in summary.types})
        materials = [registry.material_by_type(t).cls for t in present]
    types = tuple(sorted(m.particle_type for m in materials))
    for summary in seen:
        unknown = sorted(summary.types - set(types))
        if unknown:
            raise DatasetError(
                f"{source}: trajectory {summary.key!r}: particle_type: ids {unknown} belong to no material of "
                f"the model ({', '.join(m.name for m in materials)}); add them to model.materials"
            )

    property_widths = {summary.properties for summary in seen}
    if len(property_widths) > 1:
        raise DatasetError(
            f"{source}: material_property: trajectories disagree on the number of columns {sorted(property_widths)}"
        )
    num_properties = property_widths.pop() if property_widths else 0
    property_names: tuple[str, ...] = ()
    if num_properties:
        declared = model.material_properties or [p.name for m in materials for p in m.properties]
        if len(declared) != num_properties:
            raise RecipeError(
                None,
                [
                    (
                        "model.material_properties",
                        f"the data has {num_properties} material_property column(s) but the names are {declared}; "
                        "list one name per column",
                    )
                ],
            )
        property_names = tuple(declared)

    context_widths = {summary.context for summary in seen}
    if len(context_widths) > 1:
        raise DatasetError(f"{source}: step_context: trajectories disagree on its width {sorted(context_widths)}")
    context_size = context_widths.pop() if context_widths else 0
    if context_size and (metadata.context_mean is None or len(metadata.context_mean) != context_size):
        raise DatasetError(
            f"{source}: metadata.json: context_mean/context_std: needed with {context_size} entries for the "
            "step_context"
        )

    given = model.periodic if model.periodic is not None else metadata.periodic_boundary_conditions
    if given is not None and len(given) != metadata.dim:
        raise RecipeError(None, [("model.periodic", f"has {len(given)} entries but the data has dim = {metadata.dim}")])
    periodic = tuple(bool(p) for p in given) if given and any(given) else ()

    wall_conditions = _wall_conditions(seen, model.wall_conditions, bool(model.wall_features), source)

    return ModelSetup(
        dim=metadata.dim,
        bounds=tuple((float(lo), float(hi)) for lo, hi in metadata.bounds),
        connectivity_radius=float(model.connectivity_radius or metadata.default_connectivity_radius),
        particle_types=types,
        kinematic_types=tuple(sorted(m.particle_type for m in materials if m.kinematic)),
        property_names=property_names,
        context_size=context_size,
        history=model.history,
        boundary_clamp_limit=metadata.boundary_clamp_limit,
        walls=model.wall_features,
        periodic=periodic,
        wall_conditions=wall_conditions,
    )


def _wall_conditions(trajectories: Sequence[_Seen], asked: bool | None, wall_features: bool, source: str) -> bool:
    """Whether the model takes the walls' friction as inputs: as asked, or when the data's walls differ.

    Walls that are the same in every training trajectory teach the model nothing about
    friction, so by default a scene pays for the inputs only when they vary.
    """
    recorded = [t.walls for t in trajectories if t.walls is not None]
    if asked is None:
        asked = (
            wall_features
            and len(recorded) == len(trajectories)
            and any(not np.array_equal(w, recorded[0]) for w in recorded)
        )
    if not asked:
        return False
    if not wall_features:
        raise RecipeError(None, [("model.wall_conditions", "needs model.wall_features: true (the walls' distances)")])
    missing = [t.key for t in trajectories if t.walls is None]
    if missing:
        raise DatasetError(
            f"{source}: walls: model.wall_conditions needs every trajectory's face conditions; "
            f"{len(missing)} trajectory(ies) record none (first: {missing[0]!r}); generate the data with `gns generate`"
        )
    no_slip = [t.key for t in trajectories if t.walls is not None and (t.walls[:, 1] > 0).any()]  # all have walls
    if no_slip:
        raise DatasetError(
            f"{source}: walls: trajectory {no_slip[0]!r} has a no-slip face; wall conditions as model inputs "
            "cover Coulomb friction (slip = 0) only"
        )
    return True


def scene_to_dict(scene: ModelSetup) -> dict:
    """JSON-ready form of a scene (stored in checkpoints)."""
    return json.loads(json.dumps(dataclasses.asdict(scene)))


def scene_from_dict(raw: dict) -> ModelSetup:
    fields = dict(raw)
    fields["bounds"] = tuple(tuple(float(v) for v in b) for b in raw["bounds"])
    for key in ("particle_types", "kinematic_types", "property_names"):
        fields[key] = tuple(raw[key])
    fields["periodic"] = tuple(raw.get("periodic", ()))
    return ModelSetup(**fields)
