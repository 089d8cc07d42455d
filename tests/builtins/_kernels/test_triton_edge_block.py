"""The Triton edge block equals the edge update written out with concatenation, forward and backward.

On a GPU they run there (benchmarks/gpu_check.sh runs this file in its CUDA tests);
without one, Triton runs them on the CPU under ``TRITON_INTERPRET=1`` (set by
tests/conftest.py before triton is first imported), so they run in CI.
"""

from __future__ import annotations

import pytest
import torch
from float_tolerances import FLOAT32_EPS, assert_close_to_reference

from gns_builtins._kernels import triton_edge_block as triton_module
from gns_builtins._kernels.edge_block import node_table, table_rows
from gns_builtins._kernels.edge_order import EdgeOrder
from gns_framework.layers import NormedMLP

pytest.importorskip("triton")

DEVICE = torch.device("cuda" if torch.cuda.is_available() else "cpu")


@pytest.fixture(autouse=True)
def interpreted(monkeypatch):
    if DEVICE.type == "cpu" and not triton_module.interpreted():
        pytest.skip("Triton's interpreter is off (TRITON_INTERPRET=1 is set by tests/conftest.py without a GPU)")
    monkeypatch.setenv("GNS_TRITON", "interpret")


def edges(num_nodes: int, num_edges: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Random edges sorted by receiver; node 3 receives 150 of them, so its run crosses edge tiles
    (``BLOCK_EDGES``), and nodes past 16 fall in a second receiver block (``BLOCK_NODES``)."""
    generator = torch.Generator().manual_seed(seed)
    receivers = torch.cat([torch.randint(0, num_nodes, (num_edges,), generator=generator), torch.full((150,), 3)])
    senders = torch.randint(0, num_nodes, (receivers.numel(),), generator=generator)
    order = torch.argsort(receivers * num_nodes + senders)
    return senders[order], receivers[order]


def reference(mlp: NormedMLP, x, e, senders, receivers):
    """``(e + u, sum of u at receivers)`` with ``u = LN(MLP([e, x_r, x_s]))``: the paper's lines."""
    update = mlp(torch.cat([e, x[receivers], x[senders]], dim=-1))
    return e + update, torch.zeros_like(x).index_add(0, receivers, update)


def run_kernels(mlp: NormedMLP, x, e, senders, receivers, products=torch.float32):
    """The kernels on the device of ``mlp``, ``x`` and ``e``."""
    linears = mlp.mlp.linears
    senders, receivers = senders.to(x.device), receivers.to(x.device)
    weights = [linears[0].weight[:, : x.shape[1]]] + [linear.weight for linear in linears[1:]]
    biases = [linear.bias for linear in linears[1:]]
    table = node_table(x, linears[0].weight, linears[0].bias)
    rows = table_rows(senders, receivers, x.shape[0])
    order = EdgeOrder.of(senders, receivers, x.shape[0])
    norm = mlp.norm
    return triton_module.triton_edge_block(
        e, table, rows, order, weights, biases, norm.weight, norm.bias, norm.eps, products
    )


def model(hidden_layers: int, latent: int = 16, hidden: int = 32, seed: int = 0) -> NormedMLP:
    torch.manual_seed(seed)
    mlp = NormedMLP(3 * latent, hidden, hidden_layers, latent)
    with torch.no_grad():
        mlp.norm.weight.normal_()
        mlp.norm.bias.normal_()
    return mlp


def on_device(*tensors):
    return [t.to(DEVICE).requires_grad_() for t in tensors]


@pytest.mark.parametrize("hidden_layers", [1, 2])
@pytest.mark.parametrize("outputs", ["both", "edges", "aggregate"])
def test_values_and_gradients_match_float64(hidden_layers, outputs):
    n, latent = 37, 16
    senders, receivers = edges(n, 120, seed=hidden_layers)
    x = torch.randn(n, latent)
    e = torch.randn(senders.numel(), latent)
    weight_out, weight_agg = torch.randn_like(e), torch.randn_like(x)

    def loss(e_new, aggregate):
        edge_part = (e_new * weight_out.to(e_new.device)).sum() if outputs != "aggregate" else 0
        return edge_part + ((aggregate * weight_agg.to(e_new.device)).sum() if outputs != "edges" else 0)

    mlp64 = model(hidden_layers).double()
    x64, e64 = x.double().requires_grad_(), e.double().requires_grad_()
    want = reference(mlp64, x64, e64, senders, receivers)
    loss(*want).backward()
    mlp = model(hidden_layers).to(DEVICE)
    x32, e32 = on_device(x, e)
    got = run_kernels(mlp, x32, e32, senders, receivers)
    loss(*got).backward()
    for value, expected in zip(got, want, strict=True):
        assert_close_to_reference(value.detach().cpu(), expected.detach())
    assert_close_to_reference(e32.grad.cpu(), e64.grad, msg="e")
    assert_close_to_reference(x32.grad.cpu(), x64.grad, msg="x")
    for (name, p32), p64 in zip(mlp.named_parameters(), mlp64.parameters(), strict=True):
        assert_close_to_reference(p32.grad.cpu(), p64.grad, msg=name)


def test_the_comparison_catches_a_wrong_receiver():
    """The tolerance above is tight enough: one edge summed at the wrong node fails it."""
    n = 37
    senders, receivers = edges(n, 120, seed=5)
    x, e = torch.randn(n, 16), torch.randn(senders.numel(), 16)
    with torch.no_grad():
        _, aggregate = run_kernels(model(2).to(DEVICE), x.to(DEVICE), e.to(DEVICE), senders, receivers)
        wrong = receivers.clone()
        wrong[40] = wrong[40] + 1  # still sorted: the next run begins there or later
        _, want = reference(model(2).double(), x.double(), e.double(), senders, wrong)
    with pytest.raises(AssertionError):
        assert_close_to_reference(aggregate.cpu(), want)


def test_same_bits_every_run():
    mlp = model(2).to(DEVICE)
    senders, receivers = edges(37, 120, seed=2)
    x, e = on_device(torch.randn(37, 16), torch.randn(senders.numel(), 16))
    runs = []
    for _ in range(2):
        out, aggregate = run_kernels(mlp, x, e, senders, receivers)
        (out.sum() + aggregate.square().sum()).backward()
        runs.append([out.detach(), aggregate.detach(), x.grad.clone(), e.grad.clone()])
        x.grad, e.grad = None, None
    for name, first, second in zip(["edges", "aggregate", "x grad", "e grad"], *runs, strict=True):
        assert torch.equal(first, second), (name, (first - second).abs().max())


def test_bfloat16_products_within_their_rounding():
    """Products in bfloat16 (as under autocast) with float32 sums: within a few bfloat16 epsilons of float64."""
    senders, receivers = edges(37, 120, seed=3)
    x, e = torch.randn(37, 16), torch.randn(senders.numel(), 16)
    with torch.no_grad():
        mlp = model(2).to(DEVICE)
        out, aggregate = run_kernels(mlp, x.to(DEVICE), e.to(DEVICE), senders, receivers, products=torch.bfloat16)
        want_out, want_aggregate = reference(model(2).double(), x.double(), e.double(), senders, receivers)
    bfloat16_eps = torch.finfo(torch.bfloat16).eps
    ulps = 16 * bfloat16_eps / FLOAT32_EPS
    assert_close_to_reference(out.cpu(), want_out, ulps=ulps)
    assert_close_to_reference(aggregate.cpu(), want_aggregate, ulps=ulps)
    assert (out.cpu().double() - want_out).abs().max() > 16 * FLOAT32_EPS, "bfloat16 products were not used"


def test_no_edges():
    x = torch.randn(5, 16, device=DEVICE)
    empty = torch.zeros(0, dtype=torch.long)
    with torch.no_grad():
        out, aggregate = run_kernels(model(2).to(DEVICE), x, torch.zeros(0, 16, device=DEVICE), empty, empty)
    assert out.shape == (0, 16) and torch.equal(aggregate.cpu(), torch.zeros(5, 16))


def test_applies_only_where_it_can(monkeypatch):
    e = torch.zeros(3, 16, device=DEVICE)
    assert triton_module.applies(e, 32, 3)
    assert not triton_module.applies(torch.zeros(3, 12, device=DEVICE), 32, 3), "widths must be powers of two"
    assert not triton_module.applies(e, 32, 4), "at most two hidden layers"
    monkeypatch.setenv("GNS_TRITON", "0")
    assert not triton_module.applies(e, 32, 3)
    monkeypatch.delenv("GNS_TRITON")
    assert triton_module.applies(e, 32, 3) == (DEVICE.type == "cuda"), "on the CPU only when asked for"


def test_int32_indices_give_the_int64_bits():
    # Issue 45, item 4: the fixed-capacity graph on a GPU has int32 indices; the kernels widen them before a row's
    # width multiplies them, and sum the same rows in the same order.
    mlp = model(2).to(DEVICE)
    senders, receivers = edges(37, 120, seed=4)
    x, e = on_device(torch.randn(37, 16), torch.randn(senders.numel(), 16))
    runs = []
    for dtype in (torch.int64, torch.int32):
        out, aggregate = run_kernels(mlp, x, e, senders.to(dtype), receivers.to(dtype))
        (out.sum() + aggregate.square().sum()).backward()
        runs.append([out.detach(), aggregate.detach(), x.grad.clone(), e.grad.clone()])
        x.grad, e.grad = None, None
    for name, wide, narrow in zip(["edges", "aggregate", "x grad", "e grad"], *runs, strict=True):
        assert torch.equal(wide, narrow), (name, (wide - narrow).abs().max())
