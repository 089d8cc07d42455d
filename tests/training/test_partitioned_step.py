"""training.partitions: each scene split over the processes trains as one process trains it
(training/partitioned_step.py)."""

from __future__ import annotations

import pytest
import torch
from ddp_worker import train_rank
from spawned import free_loopback_port, run_processes
from training_support import tiny_recipe

from gns_framework.config.recipe import validate_recipe
from gns_framework.errors import RecipeError
from gns_framework.plugins import load_registry
from gns_framework.runtime.processes import Processes
from gns_framework.training.trainer import Trainer

STEPS = 4


@pytest.mark.parametrize("pushforward_steps", [0, 2])
def test_two_processes_that_split_each_scene_train_as_one_process(uneven_dataset, tmp_path, pushforward_steps):
    """Same losses at every step (the split forward, and the split push-forward where the recipe has one), the
    same weights after it (the summed gradients), and the same validation at the last step (split too)."""
    recipe = tiny_recipe(
        uneven_dataset,
        name="split",
        steps=STEPS,
        validate_every=1000,
        checkpoint_every=1000,
        pushforward_steps=pushforward_steps,
        validation_rollouts=1,
    )
    split = dict(recipe, training=dict(recipe["training"], partitions=2))
    run_processes(train_rank, (2, free_loopback_port(), split, str(tmp_path / "split"), [STEPS], str(tmp_path)))
    registry = load_registry()
    torch.set_num_threads(1)
    alone = Trainer(validate_recipe(recipe, registry), registry, run_dir=tmp_path / "alone", progress=False)
    losses = alone.train(STEPS)
    alone.close()
    ranks = [torch.load(tmp_path / f"rank{rank}-step{STEPS}.pt", weights_only=True) for rank in (0, 1)]
    # Both processes took every window of each step, and the same updates: bitwise the same weights.
    assert ranks[0]["windows"] == ranks[1]["windows"] == alone.order.draw(0).mine
    for name, value in ranks[0]["params"].items():
        assert torch.equal(value, ranks[1]["params"][name]), name
    # Against one process: float32 sums in another order (the unit tests check the gradients at float64).
    assert ranks[0]["losses"] == pytest.approx(losses, rel=1e-5)
    for name, value in alone.simulator.state_dict().items():
        torch.testing.assert_close(ranks[0]["params"][name], value, rtol=1e-4, atol=1e-6, msg=name)
    # Validated split: every process took part, rank 0 reports; weights 1e-4 apart move the errors as much.
    assert alone.last_validation and ranks[1]["validation"] == {}
    assert any(name.startswith("valid_rollout_") for name in alone.last_validation)
    assert ranks[0]["validation"] == pytest.approx(alone.last_validation, rel=1e-3)


def test_partitions_other_than_the_processes_are_refused(uneven_dataset, tmp_path):
    registry = load_registry()
    recipe = validate_recipe(tiny_recipe(uneven_dataset, partitions=2), registry)
    with pytest.raises(
        RecipeError,
        match=r"2 pieces need a multiple of 2 processes \(teams of one process per piece, data-parallel over the "
        r"teams\), but WORLD_SIZE is 1",
    ):
        Trainer(recipe, registry, run_dir=tmp_path / "run", processes=Processes(), progress=False)


def test_a_split_scene_refuses_components_without_a_bounded_reach(uneven_dataset, tmp_path):
    registry = load_registry()
    raw = tiny_recipe(uneven_dataset, partitions=2)
    raw["model"]["graph_builder"] = {"name": "knn", "k": 6}
    raw["model"]["processor"] = {"name": "grid_cnn", "message_passing_steps": 2, "conv_layers": 2}
    with pytest.raises(RecipeError) as refused:
        Trainer(validate_recipe(raw, registry), registry, run_dir=tmp_path / "run", progress=False)
    assert "training.partitions: graph builder 'knn' joins particles by more than their own distance" in str(
        refused.value
    )
    assert "processor 'grid_cnn' does not bound how far" in str(refused.value)


def test_two_teams_of_two_processes_train_as_one_process_on_both_teams_windows(uneven_dataset, tmp_path):
    """4 processes, partitions 2: each team splits its own windows' scenes, the teams are data-parallel, and the run
    is one process's with the global batch (both teams' windows), as for plain data-parallel training."""
    recipe = tiny_recipe(
        uneven_dataset,
        name="teams",
        steps=STEPS,
        validate_every=1000,
        checkpoint_every=1000,
        pushforward_steps=1,
        validation_rollouts=1,
    )
    split = dict(recipe, training=dict(recipe["training"], partitions=2))
    run_processes(train_rank, (4, free_loopback_port(), split, str(tmp_path / "teams"), [STEPS], str(tmp_path)), 4)
    ranks = [torch.load(tmp_path / f"rank{rank}-step{STEPS}.pt", weights_only=True) for rank in range(4)]
    assert ranks[0]["windows"] == ranks[1]["windows"] and ranks[2]["windows"] == ranks[3]["windows"]
    assert ranks[0]["windows"] != ranks[2]["windows"], "both teams trained on the same windows"
    for rank in ranks[1:]:
        assert rank["losses"] == ranks[0]["losses"]
        for name, value in ranks[0]["params"].items():
            assert torch.equal(value, rank["params"][name]), name
    single = dict(recipe, training=dict(recipe["training"], batch_size=2 * recipe["training"]["batch_size"]))
    registry = load_registry()
    torch.set_num_threads(1)
    alone = Trainer(validate_recipe(single, registry), registry, run_dir=tmp_path / "alone", progress=False)
    losses = alone.train(STEPS)
    alone.close()
    assert sorted(alone.order.draw(0).mine) == sorted(ranks[0]["windows"] + ranks[2]["windows"])
    assert ranks[0]["losses"] == pytest.approx(losses, rel=1e-5)
    for name, value in alone.simulator.state_dict().items():
        torch.testing.assert_close(ranks[0]["params"][name], value, rtol=1e-4, atol=1e-6, msg=name)
    # Rank 0's team validated (its rollouts as one process's); the others report nothing.
    assert all(rank["validation"] == {} for rank in ranks[1:])
    rollout_scores = {k: v for k, v in alone.last_validation.items() if k.startswith("valid_rollout_")}
    assert rollout_scores
    assert {k: ranks[0]["validation"][k] for k in rollout_scores} == pytest.approx(rollout_scores, rel=1e-3)
