"""Whether a ground-truth simulator can run a scene: the checks every simulator shares, then its own."""

from __future__ import annotations

from ..contracts import GroundTruthSimulator
from .scene_spec import SceneSpec


def scene_problems(simulator: GroundTruthSimulator, scene: SceneSpec) -> list[tuple[str, str]]:
    """Every problem (location, message) that stops ``simulator`` from running ``scene``.

    Shared checks: the dimension is one the simulator supports; every material is
    installed, has a constitutive model the simulator moves, and is kinematic exactly
    where it is an obstacle; a block sets only properties its material declares.
    Then the simulator's own :meth:`~gns_framework.contracts.GroundTruthSimulator.check`.
    """
    problems = []
    if scene.dim not in simulator.dims:
        problems.append(("dim", f"simulator {simulator.name!r} supports dim {simulator.dims}, got {scene.dim}"))
    materials = simulator.materials
    for where, material in scene.material_uses():
        cls = materials.get(material)
        if cls is None:
            choices = ", ".join(sorted(materials)) or "none installed"
            problems.append((f"{where}.material", f"unknown material {material!r} (installed: {choices})"))
        elif cls.constitutive_model not in simulator.constitutive_models:
            problems.append(
                (
                    f"{where}.material",
                    f"material {material!r} has constitutive model {cls.constitutive_model!r}; simulator "
                    f"{simulator.name!r} supports {', '.join(simulator.constitutive_models)}",
                )
            )
        elif cls.kinematic != where.startswith("obstacles"):
            kind = "kinematic" if cls.kinematic else "not kinematic"
            problems.append(
                (f"{where}.material", f"material {material!r} is {kind}: obstacles take kinematic materials")
            )
    for i, block in enumerate(scene.blocks):
        if block.material not in materials:
            continue
        declared = [p.name for p in materials[block.material].properties]
        for name in block.properties:
            if name not in declared:
                problems.append(
                    (
                        f"blocks[{i}].properties.{name}",
                        f"material {block.material!r} has no property {name!r} "
                        f"(it has: {', '.join(declared) or 'none'})",
                    )
                )
    return problems + simulator.check(scene)
