"""The geoelements/gns checkpoint importer (``gns_framework.importers.geoelements``), on synthetic checkpoints (the
parity suite checks real ones); the ``gns import-geoelements`` command is tested in
tests/cli/test_import_geoelements.py."""

from __future__ import annotations

from fractions import Fraction

import pytest
import torch
from geoelements_checkpoints import METADATA, batch_of, geoelements_state_dict

from gns_framework.errors import CheckpointError
from gns_framework.importers.geoelements import import_geoelements_checkpoint
from gns_framework.plugins import load_registry

REGISTRY = load_registry()


def test_sizes_scene_and_spec_are_read_from_tensor_shapes():
    state = geoelements_state_dict(latent=6, hidden=5, layers=3, steps=4, embedding=4, properties=1)
    imported = import_geoelements_checkpoint(state, METADATA, registry=REGISTRY)
    spec, scene = imported.model, imported.setup
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
    assert imported.setup.particle_types == (3, 6)
    with pytest.warns(DeprecationWarning, match=r"ImportedCheckpoint\.scene is now \.setup"):
        assert imported.scene is imported.setup  # its name until 0.2
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
        {k: p.detach() for k, p in zip(keys, theirs, strict=True)},
        METADATA,
        train_state=saved,
        particle_types=[3, 5],
        registry=REGISTRY,
    )
    assert (imported.step, imported.loss) == (2, 0.5)
    ours = dict(imported.simulator.named_parameters())
    ours_optimizer = torch.optim.Adam(ours.values(), lr=1e-3)
    ours_optimizer.load_state_dict(imported.optimizer_state)
    for key, p in zip(keys, theirs, strict=True):
        p.grad = torch.randn(p.shape, generator=generator)
        name = imported.parameter_map.name(key)
        if name is not None:
            ours[name].grad = imported.parameter_map.tensor(key, p.grad)
    optimizer.step()
    ours_optimizer.step()
    for key, p in zip(keys, theirs, strict=True):
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
