"""The parts of a training run, built from a recipe: each from the one before, and each refusal naming its field."""

from __future__ import annotations

import pytest
import torch
from tiny import tiny_recipe

from gns_framework.errors import DatasetError, RecipeError
from gns_framework.runtime.processes import Processes
from gns_framework.training.parts import _Builder, build_training_parts


def _with(recipe, **training):
    return recipe.model_copy(update={"training": recipe.training.model_copy(update=training)})


def test_one_process_gets_a_bare_model_its_windows_and_rank_zeros_validation(dataset_multimaterial, tmp_path, registry):
    recipe = _with(tiny_recipe(dataset_multimaterial, registry), validation_rollouts=3, ema_decay=0.9)
    parts = build_training_parts(recipe, registry, run_dir=tmp_path / "run")
    assert parts.run.root == tmp_path / "run" and parts.device == torch.device("cpu")
    assert parts.model is parts.simulator and parts.team is None
    # 2 train trajectories of 20 frames, history 6: 14 windows each, dealt in batches of 2.
    assert len(parts.windows) == 2 * (20 - 6) and parts.order.batch_size == 2
    assert len(parts.data.train) == 2 and parts.data.valid is not None
    assert len(parts.validation.trajectories) == 1  # min(validation_rollouts, the valid split's 1)
    assert parts.optimisation.ema is not None and parts.checkpoints.envelope is not None
    assert parts.noise_std > 0 and parts.optimizer.param_groups[0]["params"]


def test_the_same_seed_builds_the_same_weights(dataset_multimaterial, tmp_path, registry):
    recipe = tiny_recipe(dataset_multimaterial, registry)
    first = build_training_parts(recipe, registry, run_dir=tmp_path / "a").simulator.state_dict()
    second = build_training_parts(recipe, registry, run_dir=tmp_path / "b").simulator.state_dict()
    assert all(torch.equal(first[name], second[name]) for name in first)


def test_pieces_that_do_not_divide_the_processes_are_refused_by_field(dataset_multimaterial, tmp_path, registry):
    recipe = _with(tiny_recipe(dataset_multimaterial, registry), partitions=2)
    one_of_three = _Builder(recipe, registry, tmp_path, None, Processes(rank=0, world_size=3), None)
    with pytest.raises(RecipeError, match=r"training.partitions.*2 pieces need a multiple of 2 processes.*is 3"):
        one_of_three.team()


def test_trajectories_shorter_than_the_history_are_refused_naming_the_split(dataset_multimaterial, tmp_path, registry):
    recipe = tiny_recipe(dataset_multimaterial, registry, history=25)
    with pytest.raises(DatasetError, match=r"\(split train\): sequence_length: .* at most 20 frames.* = 25"):
        build_training_parts(recipe, registry, run_dir=tmp_path)


def test_a_compiled_node_side_trains_as_the_eager_one_and_leaves_the_weight_average_eager(
    dataset_multimaterial, tmp_path, registry, monkeypatch
):
    # training.compile_node_side (issue 45, item 4): the node side compiled after the weight average copied the
    # model (a copy of a compiled module would run the original's graphs). aot_eager traces what inductor compiles.
    from gns_framework.runtime import compiled
    from gns_framework.training import parts as parts_module

    torch._dynamo.reset()
    made = []
    monkeypatch.setattr(
        parts_module, "compile_node_side", lambda model: made.append(compiled.compile_node_side(model, "aot_eager"))
    )
    recipe = _with(tiny_recipe(dataset_multimaterial, registry), ema_decay=0.9)
    losses = {}
    for switch in (False, True):
        parts = build_training_parts(_with(recipe, compile_node_side=switch), registry, run_dir=tmp_path / str(switch))
        step = parts.optimisation
        losses[switch] = [float(step(k)[0]) for k in range(3)]
        if switch:
            assert made and "decoder" in made[0]
            assert parts.simulator.decoder._compiled_call_impl is not None
            assert step.ema.module.decoder._compiled_call_impl is None
    torch._dynamo.reset()
    assert losses[True] == losses[False]


def test_a_recipes_gradient_bound_holds_for_every_update_of_its_run(dataset_multimaterial, tmp_path, registry):
    recipe = tiny_recipe(dataset_multimaterial, registry)
    bounded = recipe.training.optimizer.model_copy(update={"clip_grad_norm": 1e-6})
    for optimizer, run in ((recipe.training.optimizer, "free"), (bounded, "bounded")):
        parts = build_training_parts(_with(recipe, optimizer=optimizer), registry, run_dir=tmp_path / run)
        parameters = [p for p in parts.simulator.parameters() if p.requires_grad]
        parts.optimisation(0)
        norm = torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in parameters]))
        # The update has run: the gradients it used are left scaled to the bound (to round-off), or not.
        assert (norm <= 1e-6 * (1 + 1e-4)) == (run == "bounded"), float(norm)
