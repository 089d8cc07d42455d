"""Tiny recipes and trainers for fast tests (latent 16, 2 message-passing steps)."""

from __future__ import annotations

from pathlib import Path

from gns_framework.config.recipe import Recipe, validate_recipe
from gns_framework.plugins import Registry, load_registry
from gns_framework.training.trainer import Trainer

TINY_PROCESSORS = {
    "interaction_network": {"message_passing_steps": 2},
    "shared_interaction_network": {"message_passing_steps": 2},
    "graph_attention": {"message_passing_steps": 2, "heads": 2},
    "egnn": {"message_passing_steps": 2},
    "grid_cnn": {"message_passing_steps": 2, "conv_layers": 2},
}
"""Parameters of each built-in processor at test size."""
TINY_GRAPH_BUILDERS = {
    "radius": {},
    "radius_fixed_capacity": {},
    "periodic_radius": {},
    "knn": {"k": 6},
    "radius_torch_cluster": {},
    "no_edges": {},
}
"""Parameters of each built-in graph builder at test size."""


def tiny_recipe(dataset: Path, registry: Registry | None = None, lr: float = 1e-3, **model) -> Recipe:
    """A validated recipe of a tiny model on ``dataset``; ``model`` keys override the model section."""
    return validate_recipe(tiny_recipe_mapping(dataset, lr=lr, **model), registry or load_registry())


def tiny_recipe_mapping(dataset: Path, run_dir: Path | None = None, lr: float = 1e-3, **model) -> dict:
    """The recipe mapping behind :func:`tiny_recipe`, for tests that edit it before validation."""
    raw = {
        "name": "tiny",
        "dataset": {"name": "safe", "path": str(dataset)},
        "model": {
            "latent_size": 16,
            "mlp_hidden_size": 16,
            "mlp_hidden_layers": 1,
            "type_embedding_size": 4,
            "processor": {"name": "interaction_network", "message_passing_steps": 2},
            **model,
        },
        "training": {
            "steps": 3,
            "batch_size": 2,
            "optimizer": {"lr_init": lr, "lr_min": lr, "lr_decay_steps": 1e9},
            "log_every": 1000,
            "validate_every": 100000,
            "checkpoint_every": 100000,
            "validation_windows": 16,
            "device": "cpu",
            "threads": 1,
        },
    }
    if run_dir is not None:
        raw["output_dir"] = str(run_dir)
    return raw


def tiny_trainer(recipe: Recipe, run_dir: Path, registry: Registry | None = None) -> Trainer:
    return Trainer(recipe, registry or load_registry(), run_dir=run_dir, progress=False)


def with_deposit_warning(checkpoint: Path, out: Path, threshold: float, error_pct: float = 15.0) -> Path:
    """A copy of ``checkpoint`` at ``out`` carrying a deposit warning whose score is 0 for every rollout (no weights,
    no intercept): it flags every sand scene when ``threshold`` <= 0 and none when it is above; it warns of errors
    over ``error_pct``."""
    from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint
    from gns_framework.model.deposit_warning import INPUTS, DepositWarning

    count = len(INPUTS)
    warning = DepositWarning(
        tuple(INPUTS), (0.0,) * count, (1.0,) * count, (0.0,) * count, 0.0, threshold, error_pct=error_pct
    )
    state = load_checkpoint(checkpoint, map_location="cpu")
    state.pop("format", None)
    return save_checkpoint(out, {**state, "deposit_warning": warning.to_dict()})
