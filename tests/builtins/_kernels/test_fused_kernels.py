"""The fused CPU kernels agree with the torch path (in float64), and the edge block falls back without them."""

from __future__ import annotations

import copy
from contextlib import contextmanager

import pytest
import torch
from float_tolerances import assert_close_to_reference
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins._kernels import chunked, fused_kernels
from gns_builtins._kernels import edge_block as edge_block_module
from gns_builtins._kernels.edge_block import edge_block, node_table, table_rows
from gns_framework.layers import NormedMLP

requires_kernels = pytest.mark.skipif(fused_kernels.library() is None, reason="no C compiler: fused kernels not built")

shapes = st.tuples(st.integers(1, 300), st.integers(1, 130), st.integers(1, 2))
"""(rows, width, threads): widths off the vector length, row counts below and above the thread count."""


def _seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _layer_norm64(x: torch.Tensor, gamma: torch.Tensor, beta: torch.Tensor):
    """LayerNorm of float32 ``x`` in float64: (u, mean, rstd) and the magnitude u's rounding scales with.

    Rounding x - mean costs eps * (|x| + |mean|), amplified by rstd: for nearly equal
    values of a row the float32 result is only that good, whatever the kernel.
    """
    u, mean, rstd = torch.native_layer_norm(x.double(), (x.shape[-1],), gamma.double(), beta.double(), 1e-5)
    scale = gamma.double().abs() * rstd * (x.double().abs() + mean.abs()) + beta.double().abs()
    return u, mean, rstd, scale


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
def test_layer_norm_residual_matches_torch_in_float64(shape, seed, with_bias, stats):
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
        update, expected_mean, expected_rstd, update_scale = _layer_norm64(biased, gamma, beta)
        expected_aggregate = aggregate.double().index_add(0, receivers, update)
        aggregate_scale = aggregate.double().abs().index_add(0, receivers, update_scale)

        out = torch.empty_like(e)
        mean, rstd = fused_kernels.layer_norm_residual(a, bias, gamma, beta, 1e-5, e, out, aggregate, receivers, stats)
        torch.testing.assert_close(a, biased, rtol=0, atol=0)
        assert_close_to_reference(out, e.double() + update, scale=e.double().abs() + update_scale, msg="out")
        assert_close_to_reference(aggregate, expected_aggregate, scale=aggregate_scale, msg="aggregate")
        if stats:
            row_magnitude = biased.double().abs().mean(-1, keepdim=True)
            assert_close_to_reference(mean, expected_mean, scale=row_magnitude, msg="mean")
            assert_close_to_reference(rstd, expected_rstd, scale=expected_rstd, msg="rstd")
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
    update, _, _, update_scale = _layer_norm64(a, gamma, beta)
    assert_close_to_reference(results[0][0], e.double() + update, scale=e.double().abs() + update_scale)
    for residual, aggregate in results[1:]:
        assert torch.equal(residual, results[0][0]) and torch.equal(aggregate, results[0][1])


@requires_kernels
@settings(max_examples=40, deadline=None)
@given(
    shape=shapes,
    seed=st.integers(0, 2**16),
    inputs=st.sampled_from(["both", "aggregate", "out"]),
    with_bias=st.booleans(),
)
def test_layer_norm_backward_matches_torch_in_float64(shape, seed, inputs, with_bias):
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
        # The float64 backward from the same float32 inputs, mean and rstd included.
        grad_update = torch.zeros(rows, width, dtype=torch.float64)
        if grad_aggregate is not None:
            grad_update += grad_aggregate.double()[receivers]
        if grad_out is not None:
            grad_update += grad_out.double()
        mean64, rstd64 = mean.double(), rstd.double()
        expected, expected_gamma, expected_beta = torch.ops.aten.native_layer_norm_backward(
            grad_update, a.double(), (width,), mean64, rstd64, gamma.double(), beta.double(), [True, True, True]
        )
        # grad_a = rstd * (g * gamma - mean(g * gamma) - xhat * mean(g * gamma * xhat)): its terms are of the
        # row's rstd * max |g * gamma| (1/sqrt(eps) for constant rows, e.g. width 1); the sums add those up.
        row_scale = rstd64 * (grad_update * gamma.double()).abs().amax(-1, keepdim=True)
        xhat = (a.double() - mean64) * rstd64

        grad_residual = torch.full((rows, width), 7.0)
        sums = [torch.ones(width) for _ in range(3)]
        got = fused_kernels.layer_norm_backward(
            grad_aggregate,
            receivers,
            grad_out,
            a,
            mean,
            rstd,
            gamma,
            grad_residual,
            sums[0],
            sums[1],
            sums[2] if with_bias else None,
        )
        assert_close_to_reference(got, expected, scale=row_scale, msg="grad_a")
        assert_close_to_reference(
            sums[0], 1 + expected_gamma, scale=1 + (grad_update * xhat).abs().sum(0), msg="grad_gamma"
        )
        assert_close_to_reference(sums[1], 1 + expected_beta, scale=1 + grad_update.abs().sum(0), msg="grad_beta")
        if with_bias:
            assert_close_to_reference(sums[2], 1 + expected.sum(0), scale=1 + row_scale.sum(), msg="grad_bias")
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
            assert_close_to_reference(grad_bias, expected.double().sum(0), scale=expected.double().abs().sum(0))


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


def _float64_case(mlp, x, e, senders, receivers, weight_out, weight_agg):
    """The same case in float64, where the fused kernels never apply: the reference both float32 paths meet."""
    x64, e64 = (t.detach().double().requires_grad_() for t in (x, e))
    return copy.deepcopy(mlp).double(), x64, e64, senders, receivers, weight_out.double(), weight_agg.double()


def _edge_block_outputs(mlp) -> list[str]:
    """The names of what _run_edge_block returns, in order."""
    return ["e_new", "aggregate", "grad x", "grad e"] + [f"grad {name}" for name, _ in mlp.named_parameters()]


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
def test_float32_edge_block_with_and_without_kernels(
    receivers_sorted, hidden_layers, use_edge_output, recompute, monkeypatch, two_threads
):
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
    reference = _run_edge_block(*_float64_case(*case), use_edge_output)
    for name, got_fused, got_plain, expected in zip(_edge_block_outputs(case[0]), fused, plain, reference, strict=True):
        assert_close_to_reference(got_fused, expected, msg=f"{name}, fused kernels")
        assert_close_to_reference(got_plain, expected, msg=f"{name}, torch path")


@requires_kernels
def test_float32_edge_block_comparison_catches_an_error_of_1e_4_relative(monkeypatch, two_threads):
    """The tolerance above is not so loose that a gradient 1e-4 off (840 float32 epsilons) passes."""
    monkeypatch.setattr(chunked, "ROWS_PER_THREAD", 9)
    case = _edge_block_case(2, True, 2)
    fused = _run_edge_block(*case, True)
    reference = _run_edge_block(*_float64_case(*case), True)
    for index, name in enumerate(_edge_block_outputs(case[0])):
        assert_close_to_reference(fused[index], reference[index], msg=name)
        with pytest.raises(AssertionError, match=name):
            assert_close_to_reference(fused[index] * (1 + 1e-4), reference[index], msg=name)


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
        mlp, x, e, senders, receivers = _float64_case(*case)[:5]
        update = mlp(torch.cat([e, x[receivers], x[senders]], dim=-1)).detach()
        assert_close_to_reference(e_new, e.detach() + update)
        assert_close_to_reference(aggregate, torch.zeros_like(x).index_add(0, receivers, update))
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
