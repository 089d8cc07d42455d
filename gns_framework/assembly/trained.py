"""Rebuilding a trained simulator from a checkpoint."""

from __future__ import annotations

import importlib.metadata
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from ..config.recipe import Recipe, validate_recipe, without_pickle_grant
from ..data.metadata import DatasetMetadata, parse_metadata
from ..errors import CheckpointError
from ..io.checkpoint import load_checkpoint
from ..model.deposit_warning import DepositWarning
from ..model.envelope import Envelope
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout_guard import RolloutGuard
from ..plugins import DISABLE_ENV, Registry
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
    deposit_warning: DepositWarning | None = None
    """The warning its rollouts of sand are scored with (benchmarks/learned_warning.py --record), or None."""

    def rollout_guard(self) -> RolloutGuard:
        """The boundary treatment its recipe gives rollouts (``rollout.guard``), the same in every command."""
        return RolloutGuard.from_spec(self.simulator.setup, self.recipe.rollout.guard)


def load_trained(path: str | Path, registry: Registry, device: torch.device | str = "cpu") -> LoadedModel:
    """The simulator stored in a checkpoint, with the recipe and metadata it was trained with."""
    path = Path(path)
    state = load_checkpoint(path, map_location="cpu")
    require_components(path, state["plugins"], registry)
    # A component that is not installed and not recorded with its distribution (older checkpoints)
    # is a located problem of the stored recipe (RecipeError).
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
    warning = None
    if "deposit_warning" in state:
        try:
            warning = DepositWarning.from_dict(state["deposit_warning"])
        except ValueError as exc:
            raise CheckpointError(f"{path}: deposit_warning: not a warning record ({exc})") from None
    return LoadedModel(simulator.to(device), recipe, metadata, int(state["step"]), path, envelope, warning)


def require_components(path: Path, record: Mapping, registry: Registry) -> None:
    """Refuse a checkpoint whose recorded components are not all installed, saying what to install.

    ``record`` is the checkpoint's ``plugins``, ``kind/name -> {"distribution", "version",
    "plugin"}`` (:func:`~gns_framework.assembly.learned.plugin_versions`). Left to the stored
    recipe's validation: entries recorded as one ``"distribution version"`` string (checkpoints
    written before), and components registered in process, which no distribution installs.

    Raises:
        CheckpointError: ``<path>: plugins: needs <kind> '<name>' from distribution '<dist>' <version>, ...``
            for each missing one, with the ``pip install`` that brings it, or the plugin of
            that distribution that failed to load.
    """
    problems = []
    for key, source in record.items():
        kind, _, name = str(key).partition("/")
        if not isinstance(source, Mapping) or kind not in registry.kinds() or name in registry.names(kind):
            continue
        distribution, version = source.get("distribution"), source.get("version")
        if not (isinstance(distribution, str) and isinstance(version, str)) or distribution.startswith("<"):
            continue
        problems.append(_what_to_install(kind, name, distribution, version, registry))
    if problems:
        raise CheckpointError(f"{path}: plugins: {'; '.join(problems)}")


def _what_to_install(kind: str, name: str, distribution: str, version: str, registry: Registry) -> str:
    needs = f"needs {kind} {name!r} from distribution {distribution!r} {version}"
    pin = f"pip install {distribution}=={version}"
    if broken := registry.broken_of(distribution):
        skipped = "; ".join(f"plugin entry point {b.entry_point!r} = {b.value!r} ({b.error})" for b in broken)
        return f"{needs}, whose plugin failed to load and was skipped: {skipped}"
    try:
        installed = importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return f"{needs}, which is not installed: {pin}"
    if installed != version:
        return f"{needs}; {installed} is installed, which has no {kind} {name!r}: {pin}"
    return f"{needs}, which is installed but does not provide it now: is its plugin disabled in ${DISABLE_ENV}?"
