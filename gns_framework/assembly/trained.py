"""Rebuilding a trained simulator from a checkpoint."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..config.recipe import Recipe, validate_recipe, without_pickle_grant
from ..data.metadata import DatasetMetadata, parse_metadata
from ..errors import CheckpointError
from ..io.checkpoint import load_checkpoint
from ..model.envelope import Envelope
from ..model.learned_simulator import LearnedSimulator
from ..plugins import Registry
from ..runtime.deterministic import set_deterministic_sums
from .learned import build_learned_simulator
from .scene import scene_from_dict


@dataclass
class LoadedModel:
    simulator: LearnedSimulator
    recipe: Recipe
    metadata: DatasetMetadata
    step: int
    path: Path
    envelope: Envelope | None = None
    """What the model was trained on; None for checkpoints written before envelopes were recorded."""


def load_trained(path: str | Path, registry: Registry, device: torch.device | str = "cpu") -> LoadedModel:
    """The simulator stored in a checkpoint, with the recipe and metadata it was trained with."""
    path = Path(path)
    state = load_checkpoint(path, map_location="cpu")
    # A component that is not installed is a located problem of the stored recipe (RecipeError).
    recipe = validate_recipe(without_pickle_grant(state["recipe"]), registry, f"{path} (stored recipe)")
    # Rollouts sum at nodes the way the model trained (on GPUs: ordered or atomic).
    set_deterministic_sums(recipe.training.deterministic)
    metadata = parse_metadata(state["metadata"], f"{path} (stored metadata)")
    try:
        scene = scene_from_dict(state["scene"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: scene: not a scene record ({type(exc).__name__}: {exc})") from None
    simulator = build_learned_simulator(scene, metadata, recipe.model, registry)
    try:
        # A run that kept a weight average ships it: it is what validation chose best.pt by.
        simulator.load_state_dict(state["ema"]["model"] if isinstance(state.get("ema"), dict) else state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: model: parameters do not fit the stored recipe: {exc}") from None
    simulator.eval()
    envelope = None
    if "envelope" in state:
        try:
            envelope = Envelope.from_dict(state["envelope"])
        except (TypeError, KeyError, ValueError, AttributeError) as exc:
            raise CheckpointError(f"{path}: envelope: not an envelope record ({type(exc).__name__}: {exc})") from None
    return LoadedModel(simulator.to(device), recipe, metadata, int(state["step"]), path, envelope)
