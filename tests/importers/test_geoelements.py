"""The geoelements/gns checkpoint importer, on synthetic checkpoints (the parity suite checks real ones)."""

from __future__ import annotations

import json
import re
from fractions import Fraction

import pytest
import torch
from hostile import MEMBER, write_hostile_dataset
from synthetic import soft_sphere_trajectory, synthetic_metadata

from gns_framework.assembly.trained import load_trained
from gns_framework.cli import main
from gns_framework.data.batch import ParticleBatch
from gns_framework.errors import CheckpointError
from gns_framework.importers.geoelements import import_geoelements_checkpoint
from gns_framework.importers.geoelements_layout import Architecture
from gns_framework.io.checkpoint import load_checkpoint
from gns_framework.plugins import load_registry

REGISTRY = load_registry()
METADATA = {
    "bounds": [[0.0, 1.0], [0.0, 1.0]],
    "sequence_length": 50,
    "default_connectivity_radius": 0.3,
    "dim": 2,
    "dt": 0.0025,
    "vel_mean": [0.0, -1e-3],
    "vel_std": [2e-3, 2e-3],
    "acc_mean": [0.0, 0.0],
    "acc_std": [3e-4, 3e-4],
}


def geoelements_state_dict(
    latent=6, hidden=5, layers=2, steps=2, types=9, embedding=4, properties=0, dim=2, seed=0
) -> dict[str, torch.Tensor]:
    """Random tensors under geoelements' keys and shapes (its ``LearnedSimulator`` with these sizes)."""
    node_in = 7 * dim + (embedding if types > 1 else 0) + properties
    arch = Architecture(latent, hidden, layers, steps, types, embedding, node_in, dim + 1)
    generator = torch.Generator().manual_seed(seed)
    widths = {"_encoder.node_fn": node_in, "_encoder.edge_fn": dim + 1, "edge_fn": 3 * latent, "node_fn": 2 * latent}
    state = {}
    for key in arch.keys():
        if key.startswith("_particle_type_embedding"):
            shape = (types, embedding)
        elif "NN-" not in key:
            shape = (latent,)
        else:
            k = int(key.split("NN-")[1].split(".")[0])
            block = None if "_decoder" in key else next(b for b in widths if b in key)
            fan_in = (widths[block] if block else latent) if k == 0 else hidden
            fan_out = (dim if "_decoder" in key else latent) if k == layers else hidden
            shape = (fan_out, fan_in) if key.endswith("weight") else (fan_out,)
        state[key] = torch.randn(shape, generator=generator) * 0.3
    return state


def batch_of(types, dim=2, n=12, seed=1, with_property=False) -> ParticleBatch:
    generator = torch.Generator().manual_seed(seed)
    start = torch.rand(n, 1, dim, generator=generator) * 0.8 + 0.1
    sequence = start + torch.cumsum(torch.randn(n, 6, dim, generator=generator) * 2e-3, dim=1)
    return ParticleBatch(
        position_sequence=sequence,
        particle_type=torch.tensor(types)[torch.arange(n) % len(types)],
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        material_property=torch.full((n, 1), 0.6) if with_property else None,
    )


def test_sizes_scene_and_spec_are_read_from_tensor_shapes():
    state = geoelements_state_dict(latent=6, hidden=5, layers=3, steps=4, embedding=4, properties=1)
    imported = import_geoelements_checkpoint(state, METADATA, registry=REGISTRY)
    spec, scene = imported.model, imported.scene
    assert (spec.latent_size, spec.mlp_hidden_size, spec.mlp_hidden_layers, spec.type_embedding_size) == (6, 5, 3, 4)
    assert spec.processor.params == {"message_passing_steps": 4}
    assert scene.particle_types == tuple(range(9)) and scene.kinematic_types == (3,)
    assert scene.property_names == ("friction",) and spec.material_properties == ["friction"]
    assert scene.history == 6 and scene.connectivity_radius == 0.3


def test_a_single_type_scene_folds_the_embedding_into_the_encoder_bias():
    state = geoelements_state_dict()
    full = import_geoelements_checkpoint(state, METADATA, registry=REGISTRY).simulator
    water = import_geoelements_checkpoint(state, METADATA, particle_types=[5], registry=REGISTRY).simulator
    assert water.features.type_embedding is None
    batch = batch_of([5])
    with torch.no_grad():
        difference = full.normalized_prediction(batch.position_sequence, batch) - water.normalized_prediction(
            batch.position_sequence, batch
        )
    assert difference.abs().max() < 1e-5


def test_chosen_types_keep_their_embedding_rows():
    state = geoelements_state_dict()
    imported = import_geoelements_checkpoint(state, METADATA, particle_types=[6, 3], registry=REGISTRY)
    assert imported.scene.particle_types == (3, 6)
    assert torch.equal(
        imported.simulator.features.type_embedding.weight, state["_particle_type_embedding.weight"][[3, 6]]
    )


def test_train_state_becomes_an_adam_state_that_continues_identically():
    """Adam on geoelements' parameters and on ours, fed the same (mapped) gradients, stays equal."""
    state = geoelements_state_dict(types=9)
    keys = list(state)
    theirs = [torch.nn.Parameter(state[k].clone()) for k in keys]
    optimizer = torch.optim.Adam(theirs, lr=1e-3)
    generator = torch.Generator().manual_seed(3)
    for _ in range(2):
        for p in theirs:
            p.grad = torch.randn(p.shape, generator=generator)
        optimizer.step()
    saved = {"optimizer_state": optimizer.state_dict(), "global_train_state": {"step": 2}, "loss": 0.5}
    imported = import_geoelements_checkpoint(
        {k: p.detach() for k, p in zip(keys, theirs)},
        METADATA,
        train_state=saved,
        particle_types=[3, 5],
        registry=REGISTRY,
    )
    assert (imported.step, imported.loss) == (2, 0.5)
    ours = dict(imported.simulator.named_parameters())
    ours_optimizer = torch.optim.Adam(ours.values(), lr=1e-3)
    ours_optimizer.load_state_dict(imported.optimizer_state)
    for key, p in zip(keys, theirs):
        p.grad = torch.randn(p.shape, generator=generator)
        name = imported.parameter_map.name(key)
        if name is not None:
            ours[name].grad = imported.parameter_map.tensor(key, p.grad)
    optimizer.step()
    ours_optimizer.step()
    for key, p in zip(keys, theirs):
        name = imported.parameter_map.name(key)
        if name is not None:
            assert torch.equal(ours[name].detach(), imported.parameter_map.tensor(key, p.detach())), key


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda s: s.update({"_encode_process_decode._kan.weight": torch.zeros(1)}),
            "_encode_process_decode._kan.weight: unknown key",
        ),
        (lambda s: s.pop("_encode_process_decode._decoder.node_fn.NN-1.bias"), "_decoder.node_fn.NN-1.bias: missing"),
        (
            lambda s: s.update(
                {"_encode_process_decode._processor.gnn_stacks.1.edge_fn.0.NN-0.weight": torch.zeros(5, 17)}
            ),
            "gnn_stacks.1.edge_fn.0.NN-0.weight: shape (5, 17)",
        ),
        (lambda s: s.update({"_particle_type_embedding.weight": torch.zeros(9, 4, 1)}), "expected a 2-D tensor"),
    ],
    ids=["unknown key", "missing key", "inconsistent shape", "wrong rank"],
)
def test_bad_checkpoints_name_the_file_and_the_key(tmp_path, change, message):
    state = geoelements_state_dict()
    change(state)
    path = tmp_path / "model-10.pt"
    torch.save(state, path)
    with pytest.raises(CheckpointError) as error:
        import_geoelements_checkpoint(path, METADATA, registry=REGISTRY)
    assert str(path) in str(error.value) and message in str(error.value)


def test_inputs_that_do_not_fit_are_refused():
    with pytest.raises(CheckpointError, match="3-D model, but the metadata has dim = 2"):
        import_geoelements_checkpoint(geoelements_state_dict(dim=3), METADATA, registry=REGISTRY)
    with pytest.raises(CheckpointError, match="no type embedding"):
        import_geoelements_checkpoint(geoelements_state_dict(types=1), METADATA, registry=REGISTRY)
    with pytest.raises(CheckpointError, match="type 9 is not embedded"):
        import_geoelements_checkpoint(geoelements_state_dict(), METADATA, particle_types=[5, 9], registry=REGISTRY)


def test_files_that_need_code_to_load_are_refused(tmp_path):
    path = tmp_path / "model-0.pt"
    torch.save({"weights": Fraction(1, 3)}, path)
    with pytest.raises(CheckpointError, match="not a readable geoelements model file"):
        import_geoelements_checkpoint(path, METADATA, registry=REGISTRY)


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
