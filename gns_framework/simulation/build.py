"""From a validated scene to a ready simulator: its class, parameters and physical checks."""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError

from ..contracts import GroundTruthSimulator
from ..errors import PluginError, RecipeError
from ..plugins import Registry
from ..validation import problems_from
from .scene_checks import scene_problems
from .scene_spec import SceneSpec


def build_simulator(scene: SceneSpec, registry: Registry, source: str | Path | None = None) -> GroundTruthSimulator:
    """The simulator the scene names, given every installed material; RecipeError lists what stops it."""
    try:
        cls = registry.get("simulator", scene.simulator.name)
    except PluginError as exc:
        raise RecipeError(source, [("simulator.name", str(exc))]) from None
    try:
        params = cls.Params.model_validate(scene.simulator.params)
    except ValidationError as exc:
        raise RecipeError(source, problems_from(exc, cls.Params, prefix=("simulator",))) from None
    materials = {name: registry.get("material", name) for name in registry.names("material")}
    simulator = cls(params, materials)
    problems = scene_problems(simulator, scene)
    if problems:
        raise RecipeError(source, problems)
    return simulator
