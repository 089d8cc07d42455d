"""Training from recipes: the loss falls, resume is exact, components swap by name, rollouts obey kinematics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from tiny import tiny_recipe_mapping

from gns_framework.assembly.trained import load_trained
from gns_framework.config.recipe import load_recipe, validate_recipe
from gns_framework.contracts import Params, Processor
from gns_framework.errors import CheckpointError
from gns_framework.hookspecs import hookimpl
from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint, save_checkpoint
from gns_framework.io.rollout_file import write_rollout
from gns_framework.model.rollout import rollout
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer

REPO = Path(__file__).resolve().parents[2]


def test_shipped_recipe_lowers_validation_loss(dataset_2d, tmp_path, registry):
    recipe = load_recipe(
        REPO / "recipes" / "water2d.yaml", registry, {"training": {"steps": 300, "validate_every": 300}}
    )
    trainer = Trainer(recipe, registry, run_dir=tmp_path, dataset_path=dataset_2d, progress=False)
    before = trainer.validate()["valid_one_step_loss"]
    trainer.train()
    after = trainer.validate()["valid_one_step_loss"]
    trainer.close()
    assert after < 0.6 * before, (before, after)
    assert list_checkpoints(tmp_path / "checkpoints")[-1][0] == 300


def _train(recipe_raw, registry, steps, resume=False):
    recipe = validate_recipe(recipe_raw, registry)
    trainer = Trainer(recipe, registry, progress=False)
    if resume:
        trainer.checkpoints.resume()
    losses = trainer.train(steps)
    trainer.close()
    return losses, trainer


def test_resumed_run_continues_identically(dataset_multimaterial, tmp_path, registry):
    straight, straight_trainer = _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path / "a"), registry, 6)
    first, _ = _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path / "b"), registry, 3)
    second, resumed = _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path / "b"), registry, 6, resume=True)
    assert first + second == straight
    for (name, a), (_, b) in zip(
        straight_trainer.simulator.state_dict().items(), resumed.simulator.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name


def test_checkpoint_of_another_model_is_refused(dataset_multimaterial, tmp_path, registry):
    _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path), registry, 3)
    other = tiny_recipe_mapping(dataset_multimaterial, tmp_path, latent_size=32)
    trainer = Trainer(validate_recipe(other, registry), registry, progress=False)
    with pytest.raises(CheckpointError, match=r"different model: model\.latent_size: checkpoint 16, recipe 32"):
        trainer.checkpoints.resume()


def test_an_optimizer_state_of_another_parameter_layout_is_a_clear_error(dataset_multimaterial, tmp_path, registry):
    """A processor that has since dropped a layer: the checkpoint's optimizer state has one tensor more."""
    _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path), registry, 3)
    path = list_checkpoints(tmp_path / "checkpoints")[-1][1]
    state = {k: v for k, v in load_checkpoint(path).items() if k != "format"}
    group = state["optimizer"]["param_groups"][0]
    group["params"] = group["params"] + [max(group["params"]) + 1]
    save_checkpoint(path, state)
    trainer = Trainer(
        validate_recipe(tiny_recipe_mapping(dataset_multimaterial, tmp_path), registry), registry, progress=False
    )
    with pytest.raises(CheckpointError, match=f"{path}: its model or optimizer state does not fit"):
        trainer.checkpoints.resume()


class _MeanFieldProcessor(Processor):
    """A deliberately different processor: each node sees the mean of its incoming edge latents."""

    name = "mean_field"

    class Params(Params):
        pass

    def __init__(self, params, sizes):
        super().__init__(params, sizes)
        self.mix = torch.nn.Linear(2 * sizes.latent, sizes.latent)

    def forward(self, node_latent, edge_latent, graph):
        total = torch.zeros_like(node_latent).index_add_(0, graph.receivers, edge_latent)
        count = torch.zeros(len(node_latent), 1).index_add_(0, graph.receivers, torch.ones(len(edge_latent), 1))
        return node_latent + self.mix(torch.cat([node_latent, total / count], -1)), edge_latent


class _TestProcessors:
    @staticmethod
    @hookimpl
    def gns_processors():
        return [_MeanFieldProcessor]


def test_processor_swapped_by_one_recipe_line(dataset_2d, tmp_path):
    registry = load_registry(plugins=[("test-processors", _TestProcessors)])
    raw = tiny_recipe_mapping(dataset_2d, tmp_path)
    raw["model"]["processor"] = {"name": "mean_field"}
    recipe = validate_recipe(raw, registry)
    trainer = Trainer(recipe, registry, progress=False)
    assert isinstance(trainer.simulator.processor, _MeanFieldProcessor)
    losses = trainer.train(4)
    trainer.close()
    assert len(losses) == 4 and all(np.isfinite(losses))
    assert load_checkpoint(trainer.checkpoint_dir / "checkpoint-000000004.pt")["plugins"]["processor/mean_field"]


def test_rollout_keeps_kinematic_particles_on_ground_truth(dataset_multimaterial, tmp_path, registry):
    _train(tiny_recipe_mapping(dataset_multimaterial, tmp_path), registry, 3)
    loaded = load_trained(list_checkpoints(tmp_path / "checkpoints")[-1][1], registry)
    scene = loaded.simulator.setup
    assert scene.particle_types == (3, 5, 6) and scene.kinematic_types == (3,)
    assert scene.property_names == ("friction",)
    from gns_framework.assembly.data import open_dataset

    trajectory = open_dataset(loaded.recipe.dataset, registry).split("test")[0]
    result = rollout(loaded.simulator, trajectory, steps=5)
    kinematic = trajectory.particle_type == 3
    np.testing.assert_array_equal(result.predicted[:, kinematic], result.ground_truth[:, kinematic])
    assert not np.allclose(result.predicted[:, ~kinematic], result.ground_truth[:, ~kinematic])
    path = write_rollout(tmp_path / "r.npz", result, loaded.metadata)
    with np.load(path, allow_pickle=False) as z:
        assert z["predicted_rollout"].shape == (5, trajectory.num_particles, 2)
        assert z["initial_positions"].shape == (6, trajectory.num_particles, 2)
        assert "material_property" in z.files


def test_checkpoints_are_pruned_to_keep(dataset_2d, tmp_path, registry):
    raw = tiny_recipe_mapping(dataset_2d, tmp_path)
    raw["training"].update(checkpoint_every=1, keep_checkpoints=2)
    _train(raw, registry, 5)
    assert [step for step, _ in list_checkpoints(Path(tmp_path) / "checkpoints")] == [4, 5]


def test_bfloat16_training_follows_float32_closely(dataset_2d, tmp_path, registry):
    """training.precision: bfloat16 runs the products in bfloat16: the losses move, but only a little."""
    losses = {}
    for precision in ("float32", "bfloat16"):
        raw = tiny_recipe_mapping(dataset_2d, tmp_path / precision, latent_size=32, mlp_hidden_size=32)
        raw["training"]["precision"] = precision
        losses[precision], _trainer = _train(raw, registry, 4)
    full, low = np.array(losses["float32"]), np.array(losses["bfloat16"])
    assert np.all(np.isfinite(low))
    assert not np.array_equal(full, low)
    assert np.allclose(low, full, rtol=0.05), (full, low)
