"""``gns import-geoelements`` (``gns_framework.cli.import_geoelements``): the checkpoint it writes loads, predicts as
the imported model and resumes the geoelements optimiser; its rollout reads geoelements data with no pickle grant
and refuses a hostile file; ``--particle-types`` reads a list of type ids."""

from __future__ import annotations

import argparse
import json
import re

import pytest
import torch
from geoelements_checkpoints import METADATA, batch_of, geoelements_state_dict
from hostile import MEMBER, write_hostile_dataset
from synthetic import soft_sphere_trajectory, synthetic_metadata

from gns_framework.assembly.trained import load_trained
from gns_framework.cli import main
from gns_framework.cli.import_geoelements import _type_ids
from gns_framework.importers.geoelements import import_geoelements_checkpoint
from gns_framework.io.checkpoint import load_checkpoint
from gns_framework.plugins import load_registry

REGISTRY = load_registry()


def test_command_writes_a_checkpoint_that_loads_and_resumes(tmp_path, capsys):
    state = geoelements_state_dict(properties=1)
    torch.save(state, tmp_path / "model-7.pt")
    parameters = [torch.nn.Parameter(v.clone()) for v in state.values()]
    optimizer = torch.optim.Adam(parameters, lr=1e-4)
    for p in parameters:
        p.grad = torch.ones_like(p)
    optimizer.step()
    torch.save(
        {"optimizer_state": optimizer.state_dict(), "global_train_state": {"step": 7}, "loss": 1.0},
        tmp_path / "train_state-7.pt",
    )
    dataset = tmp_path / "sand"
    dataset.mkdir()
    (dataset / "metadata.json").write_text(json.dumps({"train": METADATA, "rollout": METADATA}))
    out = tmp_path / "imported.pt"

    code = main(
        [
            "import-geoelements",
            str(tmp_path / "model-7.pt"),
            "--dataset",
            str(dataset),
            "--train-state",
            str(tmp_path / "train_state-7.pt"),
            "--particle-types",
            "3,6",
            "--out",
            str(out),
        ]
    )

    assert code == 0 and "particle types [3, 6]" in capsys.readouterr().out
    loaded = load_trained(out, REGISTRY)
    direct = import_geoelements_checkpoint(state, METADATA, particle_types=[3, 6], registry=REGISTRY).simulator
    batch = batch_of([3, 6], with_property=True)
    with torch.no_grad():
        assert torch.equal(loaded.simulator.predict_next_position(batch), direct.predict_next_position(batch))
    stored = load_checkpoint(out)
    assert stored["step"] == 7 and stored["recipe"]["dataset"] == {
        "name": "npz",
        "path": str(dataset),
        "frame_stride": 1,
        "stride_offsets": "first",
        "mirror_axes": [],
        "memory": "auto",
    }
    resumed = torch.optim.Adam(loaded.simulator.parameters())
    resumed.load_state_dict(stored["optimizer"])
    assert stored["scheduler"]["last_epoch"] == 7


def test_imported_model_rolls_out_on_geoelements_data_without_opt_in(tmp_path, capsys):
    """geoelements' .npz files hold pickles of numpy arrays only: read with no --allow-pickle."""
    trajectory = soft_sphere_trajectory(
        0,
        frames=9,
        block=3,
        particle_types=(6,),
        kinematic_floor=True,
        with_property=True,
        key="simulation_trajectory_0",
    )
    dataset = tmp_path / "sand"
    REGISTRY.get("dataset", "npz").write(dataset, synthetic_metadata([trajectory], 2), {"test": [trajectory]})
    torch.save(geoelements_state_dict(properties=1), tmp_path / "model-7.pt")
    out = tmp_path / "run" / "checkpoints" / "imported.pt"
    assert (
        main(
            [
                "import-geoelements",
                str(tmp_path / "model-7.pt"),
                "--dataset",
                str(dataset),
                "--particle-types",
                "3,6",
                "--out",
                str(out),
            ]
        )
        == 0
    )

    assert main(["rollout", "--outside-envelope", str(out), "--no-progress"]) == 0, capsys.readouterr().err
    assert "test_0000.npz: 3 steps" in capsys.readouterr().out


def test_import_never_stores_a_pickle_grant(tmp_path, capsys):
    """The option that stored the grant in the checkpoint is gone; its rollout refuses a hostile file unrun."""
    marker = tmp_path / "marker"
    dataset = write_hostile_dataset(tmp_path / "hostile", METADATA, marker)
    torch.save(geoelements_state_dict(), tmp_path / "model-7.pt")
    out = tmp_path / "run" / "checkpoints" / "imported.pt"
    command = ["import-geoelements", str(tmp_path / "model-7.pt"), "--dataset", str(dataset), "--out", str(out)]
    with pytest.raises(SystemExit):
        main([*command, "--allow-pickle"])
    assert "unrecognized arguments: --allow-pickle" in capsys.readouterr().err
    assert main(command) == 0

    assert main(["rollout", "--outside-envelope", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert not marker.exists(), "the payload ran"
    assert re.search(rf"test\.npz: {MEMBER}: refused to unpickle builtins\.exec", err), err


def test_particle_types_are_comma_separated_ids():
    assert _type_ids("5") == [5]
    assert _type_ids("3,6") == [3, 6] and _type_ids(" 3, 6 ,") == [3, 6]  # spaces and a trailing comma are fine
    with pytest.raises(argparse.ArgumentTypeError, match=r"expected comma-separated integer type ids, got '3;6'"):
        _type_ids("3;6")


def test_default_output_is_a_checkpoint_of_a_run_named_after_the_model(tmp_path, monkeypatch, capsys):
    torch.save(geoelements_state_dict(), tmp_path / "model-7.pt")
    dataset = tmp_path / "sand"
    dataset.mkdir()
    (dataset / "metadata.json").write_text(json.dumps(METADATA))
    monkeypatch.chdir(tmp_path)
    assert main(["import-geoelements", "model-7.pt", "--dataset", "sand"]) == 0
    # No --name, no --out: runs/imported-<model file stem>/checkpoints/, at geoelements' step (0: no train state).
    written = tmp_path / "runs" / "imported-model-7" / "checkpoints" / "checkpoint-000000000.pt"
    out = capsys.readouterr().out
    assert out.startswith(f"{written.relative_to(tmp_path)}: imported model-7.pt (step 0): latent 6, 2 message-passing")
    assert "with optimizer state" not in out
    assert load_checkpoint(written)["recipe"]["name"] == "imported-model-7"
