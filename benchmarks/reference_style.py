"""The in-run peer: the reference's style of computation, with our parameters.

Restated from the paper's equations, the way the public PyTorch reference
organises them: each interaction step is a PyG ``MessagePassing`` layer that
concatenates ``[x_receiver, x_sender, e]`` on every edge and runs the full edge
MLP on it (no split first layer), sums messages with PyG's scatter, and updates
nodes from ``[aggregate, x]``; the encoder runs its MLPs on whole tensors. The
first-layer columns are reordered from ours, so it computes the same function as
the simulator it is built from and the two can be timed side by side.
"""

from __future__ import annotations

import copy

import torch
from torch import Tensor, nn
from torch_geometric.nn import MessagePassing

from gns_framework.contracts import Graph
from gns_framework.layers import NormedMLP
from gns_framework.model.learned_simulator import LearnedSimulator


class ReferenceStyleInteraction(MessagePassing):
    """One step: ``e' = LN(MLP_e([x_i, x_j, e]))``, ``x' = LN(MLP_n([sum e', x]))``, residuals on both."""

    def __init__(self, edge_mlp: NormedMLP, node_mlp: NormedMLP, latent: int):
        super().__init__(aggr="add")
        self.edge_mlp = copy.deepcopy(edge_mlp)
        self.node_mlp = copy.deepcopy(node_mlp)
        with torch.no_grad():
            edge_first = self.edge_mlp.mlp.linears[0].weight
            ours = edge_first.clone()  # [e, x_receiver, x_sender]
            edge_first.copy_(torch.cat([ours[:, latent : 2 * latent], ours[:, 2 * latent :], ours[:, :latent]], 1))
            node_first = self.node_mlp.mlp.linears[0].weight
            ours = node_first.clone()  # [x, aggregate]
            node_first.copy_(torch.cat([ours[:, latent:], ours[:, :latent]], 1))

    def forward(self, x: Tensor, edge_index: Tensor, e: Tensor) -> tuple[Tensor, Tensor]:
        e_update = self.edge_updater(edge_index, x=x, edge_latent=e)
        aggregate = self.propagate(edge_index, message_value=e_update)
        x_update = self.node_mlp(torch.cat([aggregate, x], dim=-1))
        return x + x_update, e + e_update

    def edge_update(self, x_i: Tensor, x_j: Tensor, edge_latent: Tensor) -> Tensor:
        return self.edge_mlp(torch.cat([x_i, x_j, edge_latent], dim=-1))

    def message(self, message_value: Tensor) -> Tensor:
        return message_value


class ReferenceStyleProcessor(nn.Module):
    def __init__(self, steps: list[ReferenceStyleInteraction]):
        super().__init__()
        self.steps = nn.ModuleList(steps)

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        edge_index = torch.stack([graph.senders, graph.receivers])
        for step in self.steps:
            node_latent, edge_latent = step(node_latent, edge_index, edge_latent)
        return node_latent, edge_latent


class ReferenceStyleEncoder(nn.Module):
    def __init__(self, node_mlp: NormedMLP, edge_mlp: NormedMLP):
        super().__init__()
        self.node_mlp = copy.deepcopy(node_mlp)
        self.edge_mlp = copy.deepcopy(edge_mlp)

    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        return self.node_mlp(node_features), self.edge_mlp(edge_features)


def reference_style(simulator: LearnedSimulator) -> LearnedSimulator:
    """A copy of ``simulator`` (built-in MLP encoder and interaction network) computing in the reference's style."""
    peer = copy.deepcopy(simulator)
    latent = simulator.processor.steps[0].latent
    peer.encoder = ReferenceStyleEncoder(simulator.encoder.node_mlp, simulator.encoder.edge_mlp)
    peer.processor = ReferenceStyleProcessor(
        [ReferenceStyleInteraction(step.edge_mlp, step.node_mlp, latent) for step in simulator.processor.steps]
    )
    return peer
