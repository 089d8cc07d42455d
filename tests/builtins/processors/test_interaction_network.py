"""The interaction network: equivariant to any order of particles and edges, against a float64 copy."""

from __future__ import annotations

import copy

import numpy as np
import torch
from float_tolerances import assert_close_to_reference
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins.graph_builders.cell_list import radius_pairs
from gns_builtins.processors.interaction_network import InteractionNetwork
from gns_framework.contracts import Graph, ModelSizes


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
