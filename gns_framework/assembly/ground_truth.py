"""A ground-truth simulator from a validated scene file: its class, parameters and physical checks."""

from __future__ import annotations

from pathlib import Path

from ..contracts import GroundTruthSimulator
from ..errors import RecipeError
from ..ground_truth.scene_checks import scene_problems
from ..ground_truth.scene_spec import SceneSpec
from ..plugins import Registry


def build_ground_truth_simulator(
    scene: SceneSpec, registry: Registry, source: str | Path | None = None
) -> GroundTruthSimulator:
    """The simulator the scene names, given every installed material; RecipeError lists what stops it."""
    cls, params = registry.resolve("simulator", scene.simulator, ("simulator",), source)
    materials = {name: registry.get("material", name) for name in registry.names("material")}
    simulator = cls(params, materials)
    problems = scene_problems(simulator, scene)
    if problems:
        raise RecipeError(source, problems)
    return simulator
