"""The chunked edge block equals the interaction network's edge update written out with concatenation."""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels import chunked
from gns_builtins._kernels import edge_block as edge_block_module
from gns_builtins._kernels.edge_block import edge_block, node_table, table_rows
from gns_framework.layers import NormedMLP


def concatenated_update(mlp: NormedMLP, x, e, senders, receivers):
    """``e + u`` and the sum of ``u`` at receivers, with ``u = LN(MLP([e, x_r, x_s]))`` on every edge."""
    update = mlp(torch.cat([e, x[receivers], x[senders]], dim=-1))
    aggregate = torch.zeros_like(x).index_add(0, receivers, update)
    return e + update, aggregate


def split_inputs(mlp: NormedMLP, x, senders, receivers):
    """``edge_block``'s arguments: node table, its rows per edge, weights and biases."""
    linears = mlp.mlp.linears
    weights = [linears[0].weight[:, : x.shape[1]]] + [linear.weight for linear in linears[1:]]
    table = node_table(x, linears[0].weight, linears[0].bias)
    return table, table_rows(senders, receivers, x.shape[0]), weights, [linear.bias for linear in linears[1:]]


@pytest.fixture
def small_chunks(monkeypatch):
    monkeypatch.setattr(chunked, "ROWS_PER_THREAD", 7)


@pytest.mark.parametrize("hidden_layers", [0, 1, 2])
@pytest.mark.parametrize("use_edge_output", [True, False])
@pytest.mark.parametrize("recompute", [False, True])
@pytest.mark.parametrize("ordered_sums", [False, True], ids=["index_add", "ordered_sums"])
def test_values_and_gradients_match_autograd(
    small_chunks, hidden_layers, use_edge_output, recompute, ordered_sums, monkeypatch
):
    """``ordered_sums`` is the GPUs' path (segment_sum.py), run here on the CPU."""
    monkeypatch.setattr(edge_block_module, "recompute_activations", lambda: recompute)
    monkeypatch.setattr(edge_block_module, "needs_ordered_sums", lambda device: ordered_sums)
    torch.manual_seed(hidden_layers)
    n, latent, hidden = 11, 6, 5
    receivers = torch.randint(0, n, (40,)).sort().values
    senders = torch.randint(0, n, (40,))
    mlp = NormedMLP(3 * latent, hidden, hidden_layers, latent).double()
    with torch.no_grad():
        mlp.norm.weight.normal_()
        mlp.norm.bias.normal_()
    x = torch.randn(n, latent, dtype=torch.float64, requires_grad=True)
    e = torch.randn(40, latent, dtype=torch.float64, requires_grad=True)
    weight_out = torch.randn(40, latent, dtype=torch.float64)
    weight_agg = torch.randn(n, latent, dtype=torch.float64)

    def loss(e_new, aggregate):
        value = (aggregate * weight_agg).sum()
        return value + (e_new * weight_out).sum() if use_edge_output else value

    expected = concatenated_update(mlp, x, e, senders, receivers)
    expected_grads = torch.autograd.grad(loss(*expected), [x, e, *mlp.parameters()])
    table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
    got = edge_block(e, table, rows, receivers, weights, biases, mlp.norm)
    got_grads = torch.autograd.grad(loss(*got), [x, e, *mlp.parameters()])

    for a, b in zip(got, expected, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    for a, b in zip(got_grads, expected_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10)


def test_without_autograd_writes_in_place_when_asked(small_chunks):
    torch.manual_seed(0)
    n, latent = 9, 4
    receivers, senders = torch.randint(0, n, (30,)).sort().values, torch.randint(0, n, (30,))
    mlp = NormedMLP(3 * latent, 8, 2, latent)
    x, e = torch.randn(n, latent), torch.randn(30, latent)
    with torch.no_grad():
        expected = concatenated_update(mlp, x, e, senders, receivers)
        table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
        e_new, aggregate = edge_block(e, table, rows, receivers, weights, biases, mlp.norm, in_place=True)
    assert e_new is e
    torch.testing.assert_close(e_new, expected[0])
    torch.testing.assert_close(aggregate, expected[1])


def test_in_place_refuses_autograd():
    mlp = NormedMLP(6, 4, 1, 2)
    x, e = torch.randn(3, 2), torch.randn(4, 2, requires_grad=True)
    index = torch.zeros(4, dtype=torch.long)
    table, rows, weights, biases = split_inputs(mlp, x, index, index)
    with pytest.raises(ValueError, match="in_place"):
        edge_block(e, table, rows, index, weights, biases, mlp.norm, in_place=True)


@pytest.mark.parametrize("recompute", [False, True])
def test_backward_twice_on_a_retained_graph(small_chunks, recompute, monkeypatch):
    monkeypatch.setattr(edge_block_module, "recompute_activations", lambda: recompute)
    torch.manual_seed(1)
    n, latent = 9, 4
    receivers, senders = torch.randint(0, n, (30,)).sort().values, torch.randint(0, n, (30,))
    mlp = NormedMLP(3 * latent, 8, 2, latent)
    x, e = torch.randn(n, latent, requires_grad=True), torch.randn(30, latent)
    table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
    _, aggregate = edge_block(e, table, rows, receivers, weights, biases, mlp.norm)
    first = torch.autograd.grad(aggregate.sum(), x, retain_graph=True)[0]
    second = torch.autograd.grad(aggregate.sum(), x)[0]
    torch.testing.assert_close(first, second)


def test_bfloat16_autocast_is_no_less_accurate_than_autocast_on_the_concatenated_mlp(small_chunks):
    """Under autocast the products run in bfloat16 (results move), yet values and gradients
    are as close to float32 as autocast makes the unsplit MLP; outputs and gradients stay float32."""
    torch.manual_seed(0)
    n, latent, hidden, edges = 13, 32, 32, 60
    receivers = torch.randint(0, n, (edges,)).sort().values
    senders = torch.randint(0, n, (edges,))
    mlp = NormedMLP(3 * latent, hidden, 2, latent)
    x = torch.randn(n, latent, requires_grad=True)
    e = torch.randn(edges, latent, requires_grad=True)
    weight_out, weight_agg = torch.randn(edges, latent), torch.randn(n, latent)

    def chunked():
        table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
        return edge_block(e, table, rows, receivers, weights, biases, mlp.norm)

    def concatenated():
        update = mlp(torch.cat([e, x[receivers], x[senders]], dim=-1)).float()
        return e + update, torch.zeros_like(x).index_add(0, receivers, update)

    def values_and_gradients(block):
        e_new, aggregate = block()
        loss = (e_new * weight_out).sum() + (aggregate * weight_agg).sum()
        return [e_new, aggregate, *torch.autograd.grad(loss, [x, e, *mlp.parameters()])]

    full = values_and_gradients(concatenated)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        ours = values_and_gradients(chunked)
        autocast_reference = values_and_gradients(concatenated)
    for index, (a, b, c) in enumerate(zip(full, ours, autocast_reference, strict=True)):
        assert b.dtype == torch.float32, index
        a, b, c = a.detach(), b.detach(), c.detach().float()
        error = float((b - a).norm() / a.norm())
        reference_error = float((c - a).norm() / a.norm())
        assert error <= 1.2 * reference_error + 1e-6, (index, error, reference_error)
        if index < 4:  # the outputs and input gradients pass through the products
            assert error > 1e-4, (index, error)


@pytest.mark.parametrize("recompute", [False, True])
def test_under_bfloat16_autocast_the_edge_latents_are_kept_in_bfloat16_with_the_same_gradients(
    small_chunks, recompute, monkeypatch
):
    """The backward reads e only as a bfloat16 product operand: keeping e in bfloat16 halves it and changes no bit."""
    monkeypatch.setattr(edge_block_module, "recompute_activations", lambda: recompute)
    torch.manual_seed(1)
    n, latent, edges = 9, 16, 50
    receivers, senders = torch.randint(0, n, (edges,)).sort().values, torch.randint(0, n, (edges,))
    mlp = NormedMLP(3 * latent, 16, 1, latent)
    x = torch.randn(n, latent, requires_grad=True)
    e = torch.randn(edges, latent, requires_grad=True)

    def gradients():
        with torch.autocast("cpu", dtype=torch.bfloat16):
            table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
            e_new, aggregate = edge_block(e, table, rows, receivers, weights, biases, mlp.norm)
        saved = e_new.grad_fn.saved_tensors[0]
        return saved, torch.autograd.grad(e_new.square().sum() + aggregate.sum(), [x, e, *mlp.parameters()])

    saved, kept_in_bfloat16 = gradients()
    assert saved.dtype == torch.bfloat16 and saved.shape == e.shape
    # The same block with e kept as given: a cast that returns e itself.
    original_to = torch.Tensor.to
    monkeypatch.setattr(torch.Tensor, "to", lambda t, *a, **k: t if t is e else original_to(t, *a, **k))
    saved, kept_as_given = gradients()
    assert saved.dtype == torch.float32
    for a, b in zip(kept_in_bfloat16, kept_as_given, strict=True):
        assert a.dtype == b.dtype and torch.equal(a, b)


def test_a_graphs_chunk_order_gives_the_bits_of_the_per_call_sort(small_chunks, monkeypatch):
    # The accelerators' ordered sums (run here on the CPU): the senders' order made once per graph (ChunkOrder,
    # by edge_order) instead of per backward call, and receivers known sorted instead of sorted again.
    from gns_builtins._kernels.chunked import chunk_size
    from gns_builtins._kernels.edge_block import ChunkOrder, chunk_sender_order

    monkeypatch.setattr(edge_block_module, "needs_ordered_sums", lambda device: True)
    torch.manual_seed(3)
    n, latent, hidden = 13, 6, 5
    receivers, senders = torch.randint(0, n, (50,)).sort().values, torch.randint(0, n, (50,))
    mlp = NormedMLP(3 * latent, hidden, 2, latent)
    x = torch.randn(n, latent, requires_grad=True)
    e = torch.randn(50, latent, requires_grad=True)
    order = ChunkOrder(chunk_sender_order(senders, chunk_size(e.device)))
    results = []
    for given in (None, order):
        table, rows, weights, biases = split_inputs(mlp, x, senders, receivers)
        e_new, aggregate = edge_block(e, table, rows, receivers, weights, biases, mlp.norm, order=given)
        grads = torch.autograd.grad((e_new.square().sum() + aggregate.sin().sum()), [x, e, *mlp.parameters()])
        results.append([e_new, aggregate, *grads])
    for a, b in zip(*results, strict=True):
        assert torch.equal(a, b)
