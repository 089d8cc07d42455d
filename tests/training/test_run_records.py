"""What a training run records: the data it was trained on, every plugin it used, and a word when it cannot validate."""

from __future__ import annotations

import json
import warnings

import pytest
import yaml
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe, tiny_recipe_mapping

from gns_framework.cli import main
from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint
from gns_framework.training.trainer import Trainer


def test_train_records_the_dataset_option_and_rollout_uses_it(dataset_multimaterial, tmp_path):
    recipe = tmp_path / "tiny.yaml"
    raw = tiny_recipe_mapping(tmp_path / "the recipe's data, never made", tmp_path / "run")
    recipe.write_text(yaml.safe_dump(raw))
    assert (
        main(
            [
                "train",
                str(recipe),
                "--dataset",
                str(dataset_multimaterial),
                "--steps",
                "2",
                "--no-progress",
                "--no-tracking",
            ]
        )
        == 0
    )
    run = tmp_path / "run"
    checkpoint = list_checkpoints(run / "checkpoints")[-1][1]
    assert yaml.safe_load((run / "recipe.yaml").read_text())["dataset"]["path"] == str(dataset_multimaterial)
    assert json.loads((run / "params.json").read_text())["recipe"]["dataset"]["path"] == str(dataset_multimaterial)
    assert load_checkpoint(checkpoint)["recipe"]["dataset"]["path"] == str(dataset_multimaterial)
    # Without --dataset, the rollout runs on the data the model was trained on.
    assert (
        main(
            [
                "rollout",
                "--outside-envelope",
                str(checkpoint),
                "--steps",
                "2",
                "--trajectories",
                "1",
                "--no-progress",
                "--out",
                str(tmp_path / "rollouts"),
            ]
        )
        == 0
    )
    assert (tmp_path / "rollouts" / "test_0000.npz").is_file()


def test_plugin_record_names_the_materials(dataset_multimaterial, tmp_path, registry):
    trainer = Trainer(tiny_recipe(dataset_multimaterial, registry), registry, run_dir=tmp_path, progress=False)
    trainer.train(1)
    trainer.close()
    sand = registry.entry("material", "sand")
    for record in (
        json.loads((tmp_path / "params.json").read_text())["plugins"],
        trainer.checkpoints.state()["plugins"],
    ):
        assert {k for k in record if k.startswith("material/")} == {"material/rigid", "material/water", "material/sand"}
        assert record["material/sand"] == {
            "distribution": "gns-framework",
            "version": sand.version,
            "plugin": sand.plugin,
        }


@pytest.mark.parametrize("valid", [None, 0])
def test_training_without_a_valid_split_says_so_once(valid, tmp_path, registry):
    data = write_synthetic_dataset(tmp_path / "data", train=1, valid=valid or 0, test=0, frames=12, block=3)
    if valid is None:
        (data / "valid.npz").unlink()
    recipe = tiny_recipe(data, registry)
    recipe = recipe.model_copy(update={"training": recipe.training.model_copy(update={"validate_every": 1})})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trainer = Trainer(recipe, registry, run_dir=tmp_path / "run", progress=False)
        trainer.train(2)
        trainer.close()
    said = [str(w.message) for w in caught if "without validation" in str(w.message)]
    expected = "no valid split" if valid is None else "an empty valid split"
    assert len(said) == 1 and f"{data}: {expected}: training goes on without validation" in said[0]
