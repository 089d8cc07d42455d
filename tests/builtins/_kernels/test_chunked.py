"""The chunked MLP's generic parts: row chunks, product dtypes, and the hidden layers forward and backward.

The hidden layers are checked against autograd on the same MLP written with torch
operations, in float64 (the torch path: the fused kernels take float32 only) and in
float32 (the fused kernels' path where they are built), against a float64 reference.
"""

from __future__ import annotations

import pytest
import torch
from float_tolerances import assert_close_to_reference

from gns_builtins._kernels import chunked


def test_chunks_cover_the_rows_in_order_with_a_shorter_last_one():
    assert list(chunked.chunks(10, 4)) == [(0, 4), (4, 8), (8, 10)]
    assert list(chunked.chunks(8, 4)) == [(0, 4), (4, 8)]
    assert list(chunked.chunks(0, 4)) == []


def test_cpu_chunks_grow_with_the_threads_and_accelerator_chunks_are_fixed(monkeypatch):
    monkeypatch.setattr(torch, "get_num_threads", lambda: 3)
    assert chunked.chunk_size(torch.device("cpu")) == 3 * chunked.ROWS_PER_THREAD
    assert chunked.chunk_size(torch.device("cuda")) == chunked.ROWS_PER_CHUNK_ACCELERATOR


def test_widest_dtype_promotes_over_all_tensors():
    bf16, f16, f32, f64 = (
        torch.zeros(1, dtype=d) for d in (torch.bfloat16, torch.float16, torch.float32, torch.float64)
    )
    assert chunked.widest_dtype(bf16) == torch.bfloat16
    assert chunked.widest_dtype(bf16, f32) == torch.float32
    # Neither half type holds the other: they promote to float32.
    assert chunked.widest_dtype(f16, bf16) == torch.float32
    assert chunked.widest_dtype(f32, bf16, f64) == torch.float64


def test_products_run_in_autocasts_dtype_only_while_it_is_on():
    assert chunked.product_dtype(torch.float32, "cpu") == torch.float32
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert chunked.product_dtype(torch.float32, "cpu") == torch.bfloat16
    assert chunked.product_dtype(torch.float64, "cpu") == torch.float64


def test_for_products_casts_and_makes_contiguous():
    weight = torch.arange(6.0).reshape(2, 3).t()
    [cast] = chunked.for_products(torch.bfloat16, [weight])
    assert cast.dtype == torch.bfloat16 and cast.is_contiguous()
    assert torch.equal(cast.float(), weight)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_bias_relu_adds_the_bias_and_clips_in_place(dtype):
    a = torch.tensor([[-1.0, 0.5], [2.0, -3.0]], dtype=dtype)
    out = chunked.bias_relu_(a, torch.tensor([1.5, 1.0], dtype=dtype))
    assert out.data_ptr() == a.data_ptr()
    assert out.tolist() == [[0.5, 1.5], [3.5, 0.0]]
    assert chunked.bias_relu_(torch.tensor([[-1.0, 2.0]], dtype=dtype), None).tolist() == [[0.0, 2.0]]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_relu_backward_passes_the_gradient_where_the_input_was_positive(dtype):
    grad = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], dtype=dtype)
    z = torch.tensor([[0.0, 0.5, 2.0], [1.0, 0.0, 0.0]], dtype=dtype)
    grad_bias = torch.full((3,), 10.0, dtype=dtype)
    out = chunked.relu_backward(grad, z, grad_bias)
    # Zero where z = relu(a) is 0 (the ReLU's gradient there is 0, as torch takes it).
    assert out.tolist() == [[0.0, 2.0, 3.0], [4.0, 0.0, 0.0]]
    # The column sums are added to what grad_bias held.
    assert grad_bias.tolist() == [14.0, 12.0, 13.0]


def test_add_product_multiplies_in_the_operands_dtype_and_sums_in_the_totals():
    # 1 * 256 + 1 * 1 = 257 is not a bfloat16 (8 significant bits): the bfloat16 product rounds it to 256.
    a = torch.tensor([[1.0, 1.0]])
    b = torch.tensor([[256.0], [1.0]])
    total = torch.full((1, 1), 0.5)
    chunked.add_product(total, a.bfloat16(), b.bfloat16())
    assert total.dtype == torch.float32 and total.item() == 256.5
    chunked.add_product(total, a, b)
    assert total.item() == 256.5 + 257.0


def test_product_into_overwrites_the_output_in_its_dtype():
    a = torch.tensor([[1.0, 1.0]])
    b = torch.tensor([[256.0], [1.0]])
    out = torch.full((1, 1), 7.0)
    chunked.product_into(out, a.bfloat16(), b.bfloat16())
    assert out.dtype == torch.float32 and out.item() == 256.0
    chunked.product_into(out, a, b)
    assert out.item() == 257.0


def _layers(dtype, generator):
    """A first layer's output (rows 9, width 5) and two more layers, 5 -> 6 -> 4, in ``dtype``."""
    a = torch.randn(9, 5, generator=generator, dtype=torch.float64)
    weights = [
        torch.randn(6, 5, generator=generator, dtype=torch.float64),
        torch.randn(4, 6, generator=generator, dtype=torch.float64),
    ]
    biases = [
        torch.randn(6, generator=generator, dtype=torch.float64),
        torch.randn(4, generator=generator, dtype=torch.float64),
    ]
    return a.to(dtype), [w.to(dtype) for w in weights], [b.to(dtype) for b in biases]


def _autograd(a, weights, biases, grad_out):
    """relu(relu(a) W1^T + b1) W2^T + b2 in float64 with autograd: output and gradients at a, W1, b1, W2."""
    a, w1, w2, b1 = (t.detach().double().requires_grad_() for t in (a, *weights, biases[0]))
    out = torch.relu(torch.relu(a) @ w1.t() + b1) @ w2.t() + biases[1].double()
    grads = torch.autograd.grad((out * grad_out.double()).sum(), [a, w1, b1, w2])
    return out.detach(), grads


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_hidden_layers_forward_and_backward_match_autograd(dtype):
    a, weights, biases = _layers(dtype, torch.Generator().manual_seed(0))
    grad_out = torch.randn(9, 4, generator=torch.Generator().manual_seed(1), dtype=dtype)
    reference, (grad_a, grad_w1, grad_b1, grad_w2) = _autograd(a, weights, biases, grad_out)

    first = a.clone()
    inputs, product = chunked.hidden_forward(first, weights, biases)
    # The last bias is the caller's to add; relu(a) is made in a's own storage.
    assert inputs[0].data_ptr() == first.data_ptr() and len(inputs) == 2
    assert_close_to_reference(product + biases[1], reference)

    # Gradients accumulate into what the buffers held (ones), in the sums' dtype.
    grad_weights = [torch.ones_like(w) for w in weights]
    grad_biases = [torch.ones_like(b) for b in biases]
    back = chunked.hidden_backward(grad_out.clone(), inputs, weights, grad_weights, grad_biases, (dtype, dtype))
    assert_close_to_reference(back, grad_a)
    assert_close_to_reference(grad_weights[0] - 1, grad_w1, scale=grad_w1.abs().max() + 1)
    assert_close_to_reference(grad_weights[1] - 1, grad_w2, scale=grad_w2.abs().max() + 1)
    assert_close_to_reference(grad_biases[0] - 1, grad_b1, scale=grad_b1.abs().max() + 1)
    # The last layer's bias gradient (the column sum of grad_out) is left to the caller.
    assert torch.equal(grad_biases[1], torch.ones_like(biases[1]))


def test_under_bfloat16_products_the_gradient_sums_stay_in_float32():
    a, weights, biases = _layers(torch.float32, torch.Generator().manual_seed(2))
    grad_out = torch.randn(9, 4, generator=torch.Generator().manual_seed(3))
    _, (grad_a, grad_w1, _, _) = _autograd(a, weights, biases, grad_out)
    products = chunked.for_products(torch.bfloat16, weights)
    inputs, _ = chunked.hidden_forward(a.bfloat16(), products, chunked.for_products(torch.bfloat16, biases))
    grad_weights = [torch.zeros_like(w) for w in weights]
    grad_biases = [torch.zeros_like(b) for b in biases]
    back = chunked.hidden_backward(
        grad_out, inputs, products, grad_weights, grad_biases, (torch.bfloat16, torch.float32)
    )
    assert back.dtype == torch.bfloat16 and grad_weights[0].dtype == torch.float32
    # bfloat16 keeps 8 significant bits (relative rounding 2^-8 per operation), a few operations deep: 5 %.
    torch.testing.assert_close(back.double(), grad_a, rtol=0, atol=0.05 * float(grad_a.abs().max()))
    torch.testing.assert_close(grad_weights[0].double(), grad_w1, rtol=0, atol=0.05 * float(grad_w1.abs().max()))
