"""Integrator inverse, processor permutation equivariance, features sized from the scene."""

from __future__ import annotations

import copy

import numpy as np
import torch
from float_tolerances import assert_close_to_reference
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gns_builtins.graph_builders.cell_list import radius_pairs
from gns_builtins.integrators.semi_implicit_euler import SemiImplicitEuler
from gns_builtins.processors.interaction_network import InteractionNetwork
from gns_framework.contracts import Graph, ModelSizes, Scene
from gns_framework.model.features import FeatureBuilder, node_feature_size
from gns_framework.model.normalization import Stats, noise_combined_std

finite = st.floats(-10, 10, allow_nan=False, width=64)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 8), st.just(6), st.integers(2, 3)), elements=finite), st.data())
def test_semi_implicit_euler_inverse_round_trip(history, data):
    sequence = torch.from_numpy(history)
    acceleration = torch.from_numpy(data.draw(arrays(np.float64, history[:, 0].shape, elements=finite)))
    integrator = SemiImplicitEuler(SemiImplicitEuler.Params())
    next_position = integrator.next_position(sequence, acceleration)
    torch.testing.assert_close(integrator.target(sequence, next_position), acceleration, rtol=0, atol=1e-9)
    torch.testing.assert_close(integrator.next_position(sequence, integrator.target(sequence, next_position)), next_position)


def _sizes(latent=16):
    return ModelSizes(node_in=latent, edge_in=latent, latent=latent, mlp_hidden=16, mlp_hidden_layers=2, output=2, dim=2)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 40), st.integers(0, 2**31 - 1))
def test_interaction_network_is_permutation_equivariant(n, seed):
    rng = np.random.default_rng(seed)
    position = torch.from_numpy(rng.uniform(0, 1, (n, 2)).astype(np.float32))
    senders, receivers = radius_pairs(position, torch.zeros(n, dtype=torch.long), 0.3)
    torch.manual_seed(seed % 1000)
    processor = InteractionNetwork(InteractionNetwork.Params(message_passing_steps=3), _sizes())
    x, e = torch.randn(n, 16), torch.randn(len(senders), 16)
    graph = Graph(senders, receivers, position[senders] - position[receivers], n)
    out_x, out_e = processor(x, e, graph)

    perm = torch.from_numpy(rng.permutation(n))
    inverse = torch.argsort(perm)
    edge_perm = torch.from_numpy(rng.permutation(len(senders)))
    permuted = Graph(inverse[senders][edge_perm], inverse[receivers][edge_perm], graph.displacement[edge_perm], n)
    px, pe = processor(x[perm], e[edge_perm], permuted)
    # Either edge order rounds its sums differently in float32: both meet the float64 processor on the original order.
    reference = copy.deepcopy(processor).double()
    rx, re = reference(x.double(), e.double(), Graph(senders, receivers, graph.displacement.double(), n))
    for got, expected, name in ((out_x, rx, "x"), (out_e, re, "e"), (px, rx[perm], "permuted x"),
                                (pe, re[edge_perm], "permuted e")):
        assert_close_to_reference(got, expected, msg=name)


def test_noise_combined_std_matches_float32_reference():
    std = noise_combined_std([0.0011, 0.0012], 6.7e-4)
    expected = torch.sqrt(torch.FloatTensor([0.0011, 0.0012]) ** 2 + 6.7e-4**2)
    assert torch.equal(std, expected) and std.dtype == torch.float32


def _scene(**kw):
    base = dict(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,))
    return Scene(**{**base, **kw})


def test_single_material_scene_has_no_type_embedding():
    stats = Stats([0.0, 0.0], [1.0, 1.0])
    single = FeatureBuilder(_scene(), stats, 16)
    multi = FeatureBuilder(_scene(particle_types=(3, 5, 6)), stats, 16)
    assert single.type_embedding is None and sum(p.numel() for p in single.parameters()) == 0
    assert multi.type_embedding.weight.shape == (3, 16)
    assert node_feature_size(_scene(), 16) == 10 + 4
    assert node_feature_size(_scene(particle_types=(3, 5, 6), property_names=("friction",)), 16) == 10 + 4 + 16 + 1
    assert node_feature_size(_scene(walls=False), 16) == 10


def test_node_features_column_order():
    scene = _scene(particle_types=(5, 6), property_names=("friction",))
    builder = FeatureBuilder(scene, Stats([0.0, 0.0], [1.0, 1.0]), 4)
    sequence = torch.linspace(0.2, 0.3, 12).reshape(1, 6, 2).repeat(2, 1, 1)
    features = builder.node_features(sequence, torch.tensor([5, 6]), torch.tensor([[0.5], [0.7]]))
    velocity = sequence[:, 1:] - sequence[:, :-1]
    torch.testing.assert_close(features[:, :10], velocity.reshape(2, 10))
    walls = torch.cat([sequence[:, -1], 1 - sequence[:, -1]], 1) / 0.1
    torch.testing.assert_close(features[:, 10:14], walls.clamp(-1, 1))
    torch.testing.assert_close(features[:, 14:18], builder.type_embedding.weight)
    torch.testing.assert_close(features[:, 18], torch.tensor([0.5, 0.7]))


def test_recomputed_edge_encoder_keeps_only_its_input_and_gives_the_same_gradients(monkeypatch):
    from gns_builtins.encoders import mlp as encoder_module
    from gns_builtins.encoders.mlp import MLPEncoder

    torch.manual_seed(0)
    sizes = ModelSizes(node_in=5, edge_in=3, latent=16, mlp_hidden=16, mlp_hidden_layers=2, output=2, dim=2,
                       connectivity_radius=0.1)
    encoder = MLPEncoder(MLPEncoder.Params(), sizes)
    nodes, edges = torch.randn(7, 5), torch.randn(40, 3, requires_grad=True)

    def run(recompute: bool):
        monkeypatch.setattr(encoder_module, "recompute_activations", lambda: recompute)
        saved = []
        with torch.autograd.graph.saved_tensors_hooks(lambda t: saved.append(t.numel() * t.element_size()) or t, lambda t: t):
            _, edge_latent = encoder(nodes, edges)
        gradients = torch.autograd.grad(edge_latent.square().sum(), [edges, *encoder.edge_mlp.parameters()])
        return sum(saved), gradients

    stored_bytes, stored = run(False)
    recomputed_bytes, recomputed = run(True)
    for a, b in zip(stored, recomputed):
        assert torch.equal(a, b)
    # Stored, the edge MLP keeps at least its two hidden layers' inputs and its LayerNorm input: 3 x (E, 16) float32.
    assert stored_bytes - recomputed_bytes >= 3 * edges.shape[0] * 16 * 4
