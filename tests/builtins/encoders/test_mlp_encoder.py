"""The MLP encoder: recomputing the edge MLP in the backward pass stores less and gives the same gradients."""

from __future__ import annotations

import torch

from gns_framework.contracts import ModelSizes


def test_recomputed_edge_encoder_keeps_only_its_input_and_gives_the_same_gradients(monkeypatch):
    from gns_builtins.encoders import mlp as encoder_module
    from gns_builtins.encoders.mlp import MLPEncoder

    torch.manual_seed(0)
    sizes = ModelSizes(
        node_in=5, edge_in=3, latent=16, mlp_hidden=16, mlp_hidden_layers=2, output=2, dim=2, connectivity_radius=0.1
    )
    encoder = MLPEncoder(MLPEncoder.Params(), sizes)
    nodes, edges = torch.randn(7, 5), torch.randn(40, 3, requires_grad=True)

    def run(recompute: bool):
        monkeypatch.setattr(encoder_module, "recompute_activations", lambda: recompute)
        saved = []
        with torch.autograd.graph.saved_tensors_hooks(
            lambda t: saved.append(t.numel() * t.element_size()) or t, lambda t: t
        ):
            _, edge_latent = encoder(nodes, edges)
        gradients = torch.autograd.grad(edge_latent.square().sum(), [edges, *encoder.edge_mlp.parameters()])
        return sum(saved), gradients

    stored_bytes, stored = run(False)
    recomputed_bytes, recomputed = run(True)
    for a, b in zip(stored, recomputed, strict=True):
        assert torch.equal(a, b)
    # Stored, the edge MLP keeps at least its two hidden layers' inputs and its LayerNorm input: 3 x (E, 16) float32.
    assert stored_bytes - recomputed_bytes >= 3 * edges.shape[0] * 16 * 4
