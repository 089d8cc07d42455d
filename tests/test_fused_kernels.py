"""The fused CPU kernels compute what the torch path computes, and the edge block falls back without them."""

from __future__ import annotations

import math
from contextlib import contextmanager

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins import chunked, fused_kernels
from gns_builtins.layers import NormedMLP
from gns_builtins.processors import edge_block as edge_block_module
from gns_builtins.processors.edge_block import edge_block, node_table, table_rows

requires_kernels = pytest.mark.skipif(fused_kernels.library() is None, reason="no C compiler: fused kernels not built")

shapes = st.tuples(st.integers(1, 300), st.integers(1, 130), st.integers(1, 2))
"""(rows, width, threads): widths off the vector length, row counts below and above the thread count."""


def _seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


@contextmanager
def num_threads(count: int):
    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.fixture
def two_threads():
    with num_threads(2):
        yield


@requires_kernels
@settings(max_examples=40, deadline=None)
@given(shape=shapes, seed=st.integers(0, 2**16), with_bias=st.booleans(), stats=st.booleans())
def test_layer_norm_residual_matches_torch(shape, seed, with_bias, stats):
    rows, width, threads = shape
    with num_threads(threads):
        g = _seeded(seed)
        a = torch.randn(rows, width, generator=g) * 3 + 1
        bias = torch.randn(width, generator=g) if with_bias else None
        gamma, beta = torch.randn(width, generator=g), torch.randn(width, generator=g)
        e = torch.randn(rows, width, generator=g)
        nodes = max(1, rows // 3)
        # Runs of equal receivers that straddle the threads' shares of rows.
        receivers = torch.randint(0, nodes, (rows,), generator=g).sort().values
        aggregate = torch.randn(nodes, width, generator=g)

        biased = a + bias if with_bias else a.clone()
        expected_update, expected_mean, expected_rstd = torch.native_layer_norm(biased, (width,), gamma, beta, 1e-5)
        expected_aggregate = aggregate.index_add(0, receivers, expected_update)

        out = torch.empty_like(e)
        mean, rstd = fused_kernels.layer_norm_residual(a, bias, gamma, beta, 1e-5, e, out, aggregate, receivers, stats)
        torch.testing.assert_close(a, biased, rtol=0, atol=0)
        torch.testing.assert_close(out, e + expected_update, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(aggregate, expected_aggregate, rtol=1e-5, atol=1e-5)
        if stats:
            torch.testing.assert_close(mean, expected_mean, rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(rstd, expected_rstd, rtol=1e-4, atol=1e-6)
        else:
            assert mean is None and rstd is None


@requires_kernels
def test_layer_norm_residual_in_place_and_deterministic(two_threads):
    g = _seeded(0)
    a, e = torch.randn(1000, 128, generator=g), torch.randn(1000, 128, generator=g)
    gamma, beta = torch.randn(128, generator=g), torch.randn(128, generator=g)
    receivers = torch.randint(0, 50, (1000,), generator=g).sort().values
    results = []
    for _ in range(3):
        residual, aggregate = e.clone(), torch.zeros(50, 128)
        fused_kernels.layer_norm_residual(
            a.clone(), None, gamma, beta, 1e-5, residual, residual, aggregate, receivers, False
        )
        results.append((residual, aggregate))
    update = torch.layer_norm(a, (128,), gamma, beta, 1e-5)
    torch.testing.assert_close(results[0][0], e + update, rtol=1e-5, atol=1e-5)
    for residual, aggregate in results[1:]:
        assert torch.equal(residual, results[0][0]) and torch.equal(aggregate, results[0][1])


@requires_kernels
@settings(max_examples=40, deadline=None)
@given(shape=shapes, seed=st.integers(0, 2**16), inputs=st.sampled_from(["both", "aggregate", "out"]),
       with_bias=st.booleans())
def test_layer_norm_backward_matches_torch(shape, seed, inputs, with_bias):
    rows, width, threads = shape
    with num_threads(threads):
        g = _seeded(seed)
        a = torch.randn(rows, width, generator=g) * 2
        gamma, beta = torch.randn(width, generator=g), torch.randn(width, generator=g)
        _, mean, rstd = torch.native_layer_norm(a, (width,), gamma, beta, 1e-5)
        nodes = max(1, rows // 2)
        receivers = torch.randint(0, nodes, (rows,), generator=g)
        grad_aggregate = torch.randn(nodes, width, generator=g) if inputs != "out" else None
        grad_out = torch.randn(rows, width, generator=g) if inputs != "aggregate" else None
        grad_update = torch.zeros(rows, width)
        if grad_aggregate is not None:
            grad_update += grad_aggregate[receivers]
        if grad_out is not None:
            grad_update += grad_out
        expected, expected_gamma, expected_beta = torch.ops.aten.native_layer_norm_backward(
            grad_update, a, (width,), mean, rstd, gamma, beta, [True, True, True]
        )

        grad_residual = torch.full((rows, width), 7.0)
        sums = [torch.ones(width) for _ in range(3)]
        got = fused_kernels.layer_norm_backward(
            grad_aggregate, receivers, grad_out, a, mean, rstd, gamma, grad_residual, sums[0], sums[1],
            sums[2] if with_bias else None,
        )
        # Rounding in x - mean is amplified by rstd (1/sqrt(eps) for constant rows, e.g. width 1).
        scale = 1 + expected.abs().max().item() + (rstd.max() * grad_update.abs().max() * gamma.abs().max()).item()
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5 * scale)
        torch.testing.assert_close(sums[0], 1 + expected_gamma, rtol=1e-4, atol=1e-4 * math.sqrt(rows))
        torch.testing.assert_close(sums[1], 1 + expected_beta, rtol=1e-4, atol=1e-4 * math.sqrt(rows))
        if with_bias:
            torch.testing.assert_close(sums[2], 1 + expected.sum(0), rtol=1e-4, atol=1e-4 * math.sqrt(rows) * scale)
        else:
            assert torch.equal(sums[2], torch.ones(width))
        torch.testing.assert_close(grad_residual, grad_out if grad_out is not None else torch.full((rows, width), 7.0))


@requires_kernels
@settings(max_examples=40, deadline=None)
@given(shape=shapes, seed=st.integers(0, 2**16), with_bias=st.booleans())
def test_relu_kernels_match_torch(shape, seed, with_bias):
    rows, width, threads = shape
    with num_threads(threads):
        g = _seeded(seed)
        a, grad = torch.randn(rows, width, generator=g), torch.randn(rows, width, generator=g)
        bias = torch.randn(width, generator=g)
        a[0, 0] = -bias[0]  # exactly 0 after the bias: the ReLU's gradient there is 0, as in torch
        z = torch.relu(a + bias)
        assert torch.equal(fused_kernels.bias_relu_(a.clone(), bias), z)

        expected = torch.ops.aten.threshold_backward(grad, z, 0)
        grad_bias = torch.zeros(width) if with_bias else None
        got = fused_kernels.relu_backward_(grad.clone(), z, grad_bias)
        assert torch.equal(got, expected)
        if with_bias:
            torch.testing.assert_close(grad_bias, expected.sum(0), rtol=1e-5, atol=1e-5 * math.sqrt(rows))


@requires_kernels
def test_nan_propagates_as_in_torch():
    a = torch.tensor([[float("nan"), -1.0, 2.0]])
    z = fused_kernels.bias_relu_(a.clone(), torch.zeros(3))
    assert torch.equal(z.isnan(), torch.relu(a).isnan())
    grad = fused_kernels.relu_backward_(torch.ones(1, 3), torch.tensor([[float("nan"), 0.0, 2.0]]), None)
    expected = torch.ops.aten.threshold_backward(torch.ones(1, 3), torch.tensor([[float("nan"), 0.0, 2.0]]), 0)
    assert torch.equal(grad, expected)


def _edge_block_case(seed: int, receivers_sorted: bool, hidden_layers: int):
    torch.manual_seed(seed)
    n, edges, latent = 23, 150, 16
    receivers = torch.randint(0, n, (edges,))
    if receivers_sorted:
        receivers = receivers.sort().values
    senders = torch.randint(0, n, (edges,))
    mlp = NormedMLP(3 * latent, 12, hidden_layers, latent)
    with torch.no_grad():
        mlp.norm.weight.normal_()
        mlp.norm.bias.normal_()
    x = torch.randn(n, latent, requires_grad=True)
    e = torch.randn(edges, latent, requires_grad=True)
    weight_out, weight_agg = torch.randn(edges, latent), torch.randn(n, latent)
    return mlp, x, e, senders, receivers, weight_out, weight_agg


def _run_edge_block(mlp, x, e, senders, receivers, weight_out, weight_agg, use_edge_output):
    linears = mlp.mlp.linears
    weights = [linears[0].weight[:, : x.shape[1]]] + [linear.weight for linear in linears[1:]]
    table = node_table(x, linears[0].weight, linears[0].bias)
    rows = table_rows(senders, receivers, x.shape[0])
    e_new, aggregate = edge_block(e, table, rows, receivers, weights, [lin.bias for lin in linears[1:]], mlp.norm)
    loss = (aggregate * weight_agg).sum() + ((e_new * weight_out).sum() if use_edge_output else 0)
    grads = torch.autograd.grad(loss, [x, e, *mlp.parameters()])
    return (e_new.detach(), aggregate.detach(), *grads)


@requires_kernels
@pytest.mark.parametrize("receivers_sorted", [True, False])
@pytest.mark.parametrize("hidden_layers", [0, 2])
@pytest.mark.parametrize("use_edge_output", [True, False])
@pytest.mark.parametrize("recompute", [False, True])
def test_float32_edge_block_with_and_without_kernels(receivers_sorted, hidden_layers, use_edge_output, recompute,
                                                     monkeypatch, two_threads):
    """Values and every gradient agree between the fused and the torch path, chunk boundaries inside receiver runs."""
    monkeypatch.setattr(chunked, "ROWS_PER_THREAD", 9)
    monkeypatch.setattr(edge_block_module, "recompute_activations", lambda: recompute)
    case = _edge_block_case(hidden_layers, receivers_sorted, hidden_layers)
    calls = []
    for name in ("layer_norm_residual", "layer_norm_backward", "relu_backward_"):
        original = getattr(fused_kernels, name)
        monkeypatch.setattr(fused_kernels, name, lambda *a, _f=original, _n=name: calls.append(_n) or _f(*a))
    fused = _run_edge_block(*case, use_edge_output)
    assert "layer_norm_backward" in calls and ("layer_norm_residual" in calls) == receivers_sorted
    monkeypatch.setattr(fused_kernels, "applies", lambda *tensors: False)
    plain = _run_edge_block(*case, use_edge_output)
    for got, expected in zip(fused, plain):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)


def test_disabled_by_environment(monkeypatch):
    monkeypatch.setenv("GNS_FUSED_KERNELS", "0")
    fused_kernels.library.cache_clear()
    try:
        assert fused_kernels.library() is None
        assert not fused_kernels.applies(torch.zeros(2, 2))
    finally:
        fused_kernels.library.cache_clear()


def test_without_a_compiler_warns_once_and_the_edge_block_keeps_the_torch_path(monkeypatch, tmp_path):
    monkeypatch.setenv("CC", "false")
    monkeypatch.setenv("GNS_KERNEL_CACHE", str(tmp_path))
    fused_kernels.library.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="fused CPU kernels unavailable"):
            assert fused_kernels.library() is None
        case = _edge_block_case(0, True, 1)
        e_new, aggregate, *_ = _run_edge_block(*case, True)
        mlp, x, e, senders, receivers = case[:5]
        update = mlp(torch.cat([e, x[receivers], x[senders]], dim=-1)).detach()
        torch.testing.assert_close(e_new, e.detach() + update, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(aggregate, torch.zeros_like(x).index_add(0, receivers, update), rtol=1e-5, atol=1e-5)
        assert list(tmp_path.iterdir()) == []
    finally:
        fused_kernels.library.cache_clear()


@requires_kernels
def test_built_library_is_cached_per_source_compiler_and_cpu(monkeypatch, tmp_path):
    monkeypatch.setenv("GNS_KERNEL_CACHE", str(tmp_path))
    fused_kernels.library.cache_clear()
    try:
        assert fused_kernels.library() is not None
        built = list(tmp_path.glob("fused_kernels-*.so"))
        assert len(built) == 1
        stamp = built[0].stat().st_mtime_ns
        fused_kernels.library.cache_clear()
        assert fused_kernels.library() is not None
        assert [p.stat().st_mtime_ns for p in tmp_path.glob("fused_kernels-*.so")] == [stamp]
    finally:
        fused_kernels.library.cache_clear()
