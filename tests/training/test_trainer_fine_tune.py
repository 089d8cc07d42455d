"""Fine-tuning (gns train --init-from): step 0 from a trained model's weights, fresh optimiser, source recorded."""

from __future__ import annotations

import pytest
import torch
from training_support import tiny_recipe, write_recipe

from gns_framework.cli import main
from gns_framework.config.recipe import validate_recipe
from gns_framework.errors import CheckpointError
from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint, save_checkpoint
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer


def make_trainer(recipe: dict, run_dir) -> Trainer:
    registry = load_registry()
    return Trainer(validate_recipe(recipe, registry), registry, run_dir=run_dir, progress=False)


@pytest.fixture(scope="module")
def trained(uneven_dataset, tmp_path_factory):
    """A 4-step run with a weight average, and its checkpoint."""
    run = tmp_path_factory.mktemp("trained")
    trainer = make_trainer(tiny_recipe(uneven_dataset, steps=4, checkpoint_every=4, ema_decay=0.5), run)
    trainer.checkpoints.start_afresh()
    trainer.train(4)
    trainer.close()
    ((_, path),) = list_checkpoints(run / "checkpoints")[-1:]
    return path


def test_fine_tuning_starts_from_the_weight_average_at_step_0_with_a_fresh_optimiser(uneven_dataset, trained, tmp_path):
    source = load_checkpoint(trained)
    tuned = make_trainer(tiny_recipe(uneven_dataset, steps=8, ema_decay=0.5), tmp_path / "tuned")
    tuned.checkpoints.start_afresh()
    assert tuned.checkpoints.initialize_from(trained) == 4
    assert tuned.step == 0
    state = tuned.simulator.state_dict()
    for key, value in source["ema"]["model"].items():
        assert torch.equal(state[key], value), key
    # The weight average differs from the last weights, so taking the average is a choice that shows.
    assert any(not torch.equal(source["ema"]["model"][k], source["model"][k]) for k in source["model"])
    assert tuned.optimizer.state_dict()["state"] == {}
    assert tuned.checkpoints.state()["initialized_from"] == {"checkpoint": str(trained), "step": 4}
    assert tuned.ema is not None and torch.equal(tuned.ema.module.state_dict()[key], state[key])


def test_a_checkpoint_of_another_model_is_refused_naming_the_difference(uneven_dataset, trained, tmp_path):
    recipe = tiny_recipe(uneven_dataset)
    recipe["model"]["latent_size"] = 8
    other = make_trainer(recipe, tmp_path / "other")
    with pytest.raises(CheckpointError, match=r"model\.latent_size: checkpoint 16, recipe 8"):
        other.checkpoints.initialize_from(trained)


def test_gns_train_init_from_trains_and_records_the_source_in_every_checkpoint(
    uneven_dataset, trained, tmp_path, capsys
):
    recipe = write_recipe(tmp_path / "tuned.yaml", tiny_recipe(uneven_dataset, steps=4, checkpoint_every=2))
    run = tmp_path / "run"
    assert (
        main(["train", str(recipe), "--out", str(run), "--no-tracking", "--no-progress", "--init-from", str(trained)])
        == 0
    )
    assert f"fine-tuning from {trained} (trained 4 steps)" in capsys.readouterr().out
    written = list_checkpoints(run / "checkpoints")
    assert [step for step, _ in written] == [2, 4]
    for _, path in written:
        assert load_checkpoint(path)["initialized_from"] == {"checkpoint": str(trained), "step": 4}


def test_init_from_with_resume_is_refused_before_anything_is_written(uneven_dataset, trained, tmp_path, capsys):
    recipe = write_recipe(tmp_path / "tuned.yaml", tiny_recipe(uneven_dataset))
    run = tmp_path / "run"
    code = main(["train", str(recipe), "--out", str(run), "--no-tracking", "--resume", "--init-from", str(trained)])
    assert code != 0
    assert "--init-from and --resume" in capsys.readouterr().err
    assert not run.exists()


def test_a_radius_spelled_out_is_the_same_model_and_another_radius_is_refused(uneven_dataset, trained, tmp_path):
    radius = load_checkpoint(trained)["scene"]["connectivity_radius"]
    same = tiny_recipe(uneven_dataset)
    same["model"]["connectivity_radius"] = radius
    make_trainer(same, tmp_path / "same").checkpoints.initialize_from(trained)
    other = tiny_recipe(uneven_dataset)
    other["model"]["connectivity_radius"] = 2 * radius
    with pytest.raises(CheckpointError, match="scene: written for"):
        make_trainer(other, tmp_path / "other").checkpoints.initialize_from(trained)


def test_the_fine_tuned_envelope_holds_the_source_models_data_too(uneven_dataset, trained, tmp_path):
    # The source model saw scenes of 1 to 10^6 particles (as if its data were another dataset's).
    state = load_checkpoint(trained)
    state["envelope"]["particle_count"] = [1, 10**6]
    source = save_checkpoint(tmp_path / "source.pt", state)
    tuned = make_trainer(tiny_recipe(uneven_dataset), tmp_path / "tuned")
    own = list(tuned.checkpoints.envelope.particle_count)
    assert own != [1, 10**6]
    tuned.checkpoints.initialize_from(source)
    assert tuned.checkpoints.state()["envelope"]["particle_count"] == [1, 10**6]


def test_a_fine_tuning_may_change_the_training_noise_and_keeps_the_normalisation_its_weights_learned(
    uneven_dataset, trained, tmp_path
):
    source = load_checkpoint(trained)
    recipe = tiny_recipe(uneven_dataset)
    recipe["model"]["noise_relative"] = 0.03
    quiet = make_trainer(recipe, tmp_path / "quiet")
    # Built from the data with the new noise, the acceleration scale differs from the checkpoint's ...
    stats = [k for k in source["model"] if k.endswith(".std")]
    assert stats and any(not torch.equal(quiet.simulator.state_dict()[k], source["ema"]["model"][k]) for k in stats)
    quiet.checkpoints.initialize_from(trained)
    # ... and the checkpoint's, which its weights were learned against, replaces it; the noise is the new one.
    for key in stats:
        assert torch.equal(quiet.simulator.state_dict()[key], source["ema"]["model"][key]), key
    assert (
        quiet.optimisation.noise_std
        != make_trainer(tiny_recipe(uneven_dataset), tmp_path / "loud").optimisation.noise_std
    )


def test_a_resumed_run_must_keep_its_training_noise(uneven_dataset, trained, tmp_path):
    recipe = tiny_recipe(uneven_dataset)
    recipe["model"]["noise_relative"] = 0.03
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    state = {k: v for k, v in load_checkpoint(trained).items() if k != "format"}
    save_checkpoint(run / "checkpoints" / trained.name, state)
    with pytest.raises(CheckpointError, match=r"model\.noise_relative: checkpoint .*, recipe 0\.03"):
        make_trainer(recipe, run).checkpoints.resume()
