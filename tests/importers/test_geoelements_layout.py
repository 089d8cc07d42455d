"""Where each geoelements/gns parameter goes (``gns_framework.importers.geoelements_layout``): key names, the
permuted input columns of the first processor layers, the sizes read from tensor shapes, and a single type's
embedding folded into the encoder's first bias. Each check is against what the layer computes, not only shapes."""

from __future__ import annotations

import pytest
import torch
from geoelements_checkpoints import geoelements_state_dict

from gns_framework.errors import CheckpointError
from gns_framework.importers.geoelements_layout import (
    EMBEDDING_KEY,
    ENCODER_NODE_FIRST_BIAS,
    ENCODER_NODE_FIRST_WEIGHT,
    Architecture,
    ParameterMap,
    built_in_name,
    edge_inputs_to_ours,
    node_inputs_to_ours,
)

PREFIX = "_encode_process_decode."


@pytest.mark.parametrize(
    "key, ours",
    [
        ("_encoder.node_fn.0.NN-1.weight", "encoder.node_mlp.mlp.linears.1.weight"),
        ("_encoder.edge_fn.1.bias", "encoder.edge_mlp.norm.bias"),
        ("_processor.gnn_stacks.11.edge_fn.0.NN-0.bias", "processor.steps.11.edge_mlp.mlp.linears.0.bias"),
        ("_processor.gnn_stacks.3.node_fn.1.weight", "processor.steps.3.node_mlp.norm.weight"),
        ("_decoder.node_fn.NN-2.weight", "decoder.mlp.linears.2.weight"),
    ],
)
def test_each_geoelements_key_names_its_built_in_parameter(key, ours):
    assert built_in_name(PREFIX + key) == ours


def test_keys_without_a_counterpart_map_to_none():
    assert built_in_name(EMBEDDING_KEY) is None  # the embedding is handled apart (rows kept or folded)
    assert built_in_name("_encoder.node_fn.0.NN-0.weight") is None  # outside _encode_process_decode
    assert built_in_name(PREFIX + "_encoder.node_fn.2.weight") is None  # no such module in geoelements
    assert built_in_name(PREFIX + "_decoder.node_fn.NN-0.weight.extra") is None  # the whole key must match


def test_permuted_first_layers_compute_what_geoelements_computes():
    latent, hidden = 3, 4
    generator = torch.Generator().manual_seed(0)
    receiver, sender, edge, aggregate, node = (torch.randn(latent, generator=generator) for _ in range(5))
    edge_weight = torch.randn(hidden, 3 * latent, generator=generator)
    node_weight = torch.randn(hidden, 2 * latent, generator=generator)
    # geoelements concatenates [receiver, sender, edge] and [aggregate, node]; the built-ins [edge, receiver,
    # sender] and [node, aggregate]. A permutation moves values only: the products differ only in summation
    # order, float32 round-off of sums of order 1, hence 1e-6.
    ours = edge_inputs_to_ours(edge_weight, latent) @ torch.cat([edge, receiver, sender])
    torch.testing.assert_close(ours, edge_weight @ torch.cat([receiver, sender, edge]), rtol=0, atol=1e-6)
    ours = node_inputs_to_ours(node_weight, latent) @ torch.cat([node, aggregate])
    torch.testing.assert_close(ours, node_weight @ torch.cat([aggregate, node]), rtol=0, atol=1e-6)


def test_sizes_are_read_from_tensor_shapes():
    state = geoelements_state_dict(latent=6, hidden=5, layers=3, steps=4, types=9, embedding=4, dim=3)
    arch = Architecture.infer(state, "model-1.pt")
    assert arch == Architecture(
        latent=6,
        mlp_hidden=5,
        mlp_hidden_layers=3,
        message_passing_steps=4,
        num_types=9,
        embedding_size=4,
        node_in=7 * 3 + 4,  # (C - 1) d velocities + 2 d wall distances + the embedding, C = 6
        edge_in=4,  # d displacement components + the distance
    )
    assert arch.dim == 3 and arch.uses_embedding
    assert sorted(arch.keys()) == sorted(state)
    # geoelements embeds types only when built with more than one.
    assert not Architecture.infer(geoelements_state_dict(types=1), "m").uses_embedding


def test_without_hidden_layers_the_mlp_width_is_the_latent_size():
    arch = Architecture.infer(geoelements_state_dict(latent=6, hidden=5, layers=0), "m")
    assert (arch.mlp_hidden_layers, arch.mlp_hidden) == (0, 6)


def test_what_is_not_a_geoelements_state_dict_is_named():
    with pytest.raises(CheckpointError, match=r"m\.pt: no _encode_process_decode\._encoder / _processor keys"):
        Architecture.infer({"weights": torch.zeros(1)}, "m.pt")
    state = geoelements_state_dict()
    del state[PREFIX + "_encoder.node_fn.1.weight"]
    with pytest.raises(CheckpointError, match=r"m.pt: _encode_process_decode._encoder.node_fn.1.weight: missing"):
        Architecture.infer(state, "m.pt")
    state = geoelements_state_dict()
    state[EMBEDDING_KEY] = state[EMBEDDING_KEY][0]
    with pytest.raises(CheckpointError, match=r"_particle_type_embedding.weight: expected a 2-D tensor, got \(4,\)"):
        Architecture.infer(state, "m.pt")


def test_a_single_type_embedding_folds_into_the_encoder_bias():
    state = geoelements_state_dict(latent=6, hidden=5, types=9, embedding=4)
    arch = Architecture.infer(state, "m")
    walls = 7 * 2  # node features before the embedding in 2D
    parameter_map = ParameterMap(arch, (5,), walls)
    ours = parameter_map.state_dict(state)
    assert parameter_map.folds_embedding and parameter_map.name(EMBEDDING_KEY) is None
    assert "features.type_embedding.weight" not in ours
    features = torch.randn(walls, generator=torch.Generator().manual_seed(1))
    row = state[EMBEDDING_KEY][5]
    theirs = state[ENCODER_NODE_FIRST_WEIGHT] @ torch.cat([features, row]) + state[ENCODER_NODE_FIRST_BIAS]
    weight = ours["encoder.node_mlp.mlp.linears.0.weight"]
    assert weight.shape == (5, walls)
    # Same first-layer output without the embedding columns: float32 sums of ~18 terms of order 1, so 1e-5.
    torch.testing.assert_close(
        weight @ features + ours["encoder.node_mlp.mlp.linears.0.bias"], theirs, atol=1e-5, rtol=0
    )


def test_several_types_keep_their_embedding_rows_in_the_scene_order():
    state = geoelements_state_dict(types=9)
    parameter_map = ParameterMap(Architecture.infer(state, "m"), (3, 6), 14)
    ours = parameter_map.state_dict(state)
    assert not parameter_map.folds_embedding
    assert torch.equal(ours["features.type_embedding.weight"], state[EMBEDDING_KEY][[3, 6]])
    # Nothing else changes: the encoder keeps every column, the processor's first layers are permuted.
    assert torch.equal(ours["encoder.node_mlp.mlp.linears.0.weight"], state[ENCODER_NODE_FIRST_WEIGHT])
    key = PREFIX + "_processor.gnn_stacks.1.edge_fn.0.NN-0.weight"
    assert torch.equal(ours["processor.steps.1.edge_mlp.mlp.linears.0.weight"], edge_inputs_to_ours(state[key], 6))
