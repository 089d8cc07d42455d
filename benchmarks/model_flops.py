"""Dense (matrix-product) FLOPs of one forward pass of the reference model.

Counts 2 * rows * in * out for every Linear, with rows = N for node MLPs and
E for edge MLPs. ``split_first_layer`` counts the interaction network's first
edge layer as we compute it (node columns once per node, edge columns per
edge); without it, as the reference does (all 3L columns per edge).
"""

from __future__ import annotations

from gns_framework.model.learned_simulator import LearnedSimulator


def _linears(mlp_owner) -> list:
    return list(mlp_owner.mlp.linears)


def _flops(linears, rows: int) -> int:
    return sum(2 * rows * linear.in_features * linear.out_features for linear in linears)


def forward_flops(simulator: LearnedSimulator, num_nodes: int, num_edges: int, split_first_layer: bool = True) -> int:
    encoder, decoder = simulator.encoder, simulator.decoder
    total = _flops(_linears(encoder.node_mlp), num_nodes) + _flops(_linears(encoder.edge_mlp), num_edges)
    for step in simulator.processor.steps:
        first, *rest = _linears(step.edge_mlp)
        if split_first_layer:
            latent = step.latent
            total += 2 * num_nodes * 2 * latent * first.out_features + 2 * num_edges * latent * first.out_features
        else:
            total += _flops([first], num_edges)
        total += _flops(rest, num_edges) + _flops(_linears(step.node_mlp), num_nodes)
    return total + _flops(_linears(decoder), num_nodes)
