"""The interaction network: equivariant to any order of particles and edges, against a float64 copy."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from float_tolerances import assert_close_to_reference
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins._kernels.cell_list import radius_pairs
from gns_builtins.processors.interaction_network import InteractionNetwork
from gns_framework.contracts import Graph, ModelSizes


def _sizes(latent=16):
    return ModelSizes(
        node_in=latent, edge_in=latent, latent=latent, mlp_hidden=16, mlp_hidden_layers=2, output=2, dim=2
    )


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
    for got, expected, name in (
        (out_x, rx, "x"),
        (out_e, re, "e"),
        (px, rx[perm], "permuted x"),
        (pe, re[edge_perm], "permuted e"),
    ):
        assert_close_to_reference(got, expected, msg=name)


def _processors(steps=3, latent=16, seed=0):
    """The same weights as a fused and as a plain processor."""
    torch.manual_seed(seed)
    fused = InteractionNetwork(InteractionNetwork.Params(message_passing_steps=steps), _sizes(latent))
    plain = InteractionNetwork(
        InteractionNetwork.Params(message_passing_steps=steps, edge_block="plain"), _sizes(latent)
    )
    plain.load_state_dict(fused.state_dict())
    return fused, plain


def _graph_and_latents(n=60, latent=16, seed=0, dtype=torch.float32):
    rng = np.random.default_rng(seed)
    position = torch.from_numpy(rng.uniform(0, 1, (n, 2)).astype(np.float32))
    senders, receivers = radius_pairs(position, torch.zeros(n, dtype=torch.long), 0.25)
    graph = Graph(senders, receivers, position[senders] - position[receivers], n)
    generator = torch.Generator().manual_seed(seed)
    x = torch.randn(n, latent, generator=generator, dtype=dtype)
    e = torch.randn(len(senders), latent, generator=generator, dtype=dtype)
    return graph, x, e


def _values_and_gradients(processor, graph, x, e):
    """The processor's outputs and the gradients of a fixed readout at inputs and weights."""
    x, e = x.clone().requires_grad_(), e.clone().requires_grad_()
    out_x, out_e = processor(x, e, graph)

    # Unequal positive weights per entry, so an error in any entry's gradient shows and sums over
    # entries do not cancel to nothing; both outputs weigh alike.
    def weights(out):
        return torch.linspace(0.5, 1.5, out.numel(), dtype=out.dtype).view_as(out)

    readout = (out_x * weights(out_x)).sum() + (out_e * weights(out_e)).sum()
    grads = torch.autograd.grad(readout, [x, e, *processor.parameters()])
    return [out_x, out_e, *grads]


def test_the_plain_step_is_the_papers_three_lines():
    """plain, against the step written out here from the paper: edge update, sum at receivers, node update."""
    _fused, plain = _processors(steps=1)
    graph, x, e = _graph_and_latents()
    step = plain.steps[0]
    s, r = graph.senders, graph.receivers
    e_update = step.edge_mlp(torch.cat([e, x[r], x[s]], dim=-1))
    aggregate = torch.stack([e_update[r == i].sum(0) for i in range(x.shape[0])])
    x_update = step.node_mlp(torch.cat([x, aggregate], dim=-1))
    out_x, out_e = plain(x, e, graph)
    torch.testing.assert_close(out_x, x + x_update)
    torch.testing.assert_close(out_e, e + e_update)


def test_the_fused_step_equals_the_plain_one_in_float64():
    fused, plain = _processors()
    graph, x, e = _graph_and_latents(dtype=torch.float64)
    fused, plain = fused.double(), plain.double()
    for got, expected in zip(
        _values_and_gradients(fused, graph, x, e), _values_and_gradients(plain, graph, x, e), strict=True
    ):
        # Both are float64 evaluations of one function: they differ by float64 rounding only.
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-11 * max(float(expected.detach().abs().max()), 1.0))


def test_fused_and_plain_in_float32_both_meet_the_float64_step():
    """Values and input gradients of either float32 path against the float64 step, at the default 16 epsilons.

    The weight gradients are sums over ~550 edges whose terms cancel (LayerNorm backward),
    so their largest value is no scale for their rounding; the float64 test above proves
    them equal between the paths.
    """
    fused, plain = _processors()
    graph, x, e = _graph_and_latents()
    reference = _values_and_gradients(copy.deepcopy(plain).double(), graph, x.double(), e.double())[:4]
    for processor in (fused, plain):
        got = _values_and_gradients(processor, graph, x, e)[:4]
        for name, value, expected in zip(("x", "e", "grad x", "grad e"), got, reference, strict=True):
            assert_close_to_reference(value, expected, msg=f"{processor.params.edge_block}: {name}")


def test_the_comparison_catches_a_step_that_swaps_senders_and_receivers():
    # A plain step that concatenates [e, x_sender, x_receiver] is a different model: the check fails on it.
    fused, plain = _processors()
    graph, x, e = _graph_and_latents()
    swapped = Graph(graph.receivers, graph.senders, graph.displacement, graph.num_nodes)
    reference = _values_and_gradients(copy.deepcopy(fused).double(), graph, x.double(), e.double())
    wrong = _values_and_gradients(plain, swapped, x, e)
    with pytest.raises(AssertionError):
        assert_close_to_reference(wrong[0], reference[0])


def test_the_triton_path_meets_the_float64_step(monkeypatch):
    """Where the Triton kernels take the fused block (CUDA; here their CPU interpreter), the processor's values and
    input gradients meet the float64 plain step as the other paths do; the graph's edge order is made once."""
    pytest.importorskip("triton")
    from gns_builtins._kernels import edge_order, triton_edge_block

    if not triton_edge_block.interpreted():
        pytest.skip("Triton's interpreter is off (tests/conftest.py sets TRITON_INTERPRET=1 without a GPU)")
    monkeypatch.setenv("GNS_TRITON", "interpret")
    made = []
    monkeypatch.setattr(edge_order.EdgeOrder, "of", lambda *args, f=edge_order.EdgeOrder.of: made.append(1) or f(*args))
    fused, plain = _processors(latent=16)
    graph, x, e = _graph_and_latents(n=40)
    sorted_graph = Graph(graph.senders, graph.receivers, graph.displacement, graph.num_nodes, receivers_sorted=True)
    reference = _values_and_gradients(copy.deepcopy(plain).double(), graph, x.double(), e.double())[:4]
    got = _values_and_gradients(fused, sorted_graph, x, e)[:4]
    assert len(made) == 1, "the edge order is made once per graph, for every step"
    for name, value, expected in zip(("x", "e", "grad x", "grad e"), got, reference, strict=True):
        assert_close_to_reference(value, expected, msg=f"triton: {name}")
    _values_and_gradients(fused, graph, x, e)
    assert len(made) == 1, "a graph that does not say its receivers are sorted keeps the chunked path"
