"""The learned simulator under extreme input: forward, backward and second-order passes stay finite."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gns_framework.model.features import safe_norm
from gns_framework.plugins import load_registry
from gns_framework.stability.extreme import CASES, check_finite, tiny_simulator

pytestmark = [pytest.mark.stability, pytest.mark.usefixtures("one_torch_thread")]

REGISTRY = load_registry()
DTYPES = [torch.float32, torch.bfloat16]


@pytest.fixture(scope="module", params=[2, 3], ids=["2D", "3D"])
def reference_model(request):
    return request.param, tiny_simulator(REGISTRY, request.param)


@pytest.mark.parametrize("dtype", DTYPES, ids=["float32", "bfloat16"])
@pytest.mark.parametrize("case", list(CASES))
def test_reference_model_stays_finite(reference_model, case, dtype):
    dim, simulator = reference_model
    outcome = check_finite(simulator, CASES[case](dim, torch.Generator().manual_seed(0)), dtype)
    assert outcome.finite, outcome.failures


@pytest.mark.parametrize("processor", ["shared_interaction_network", "graph_attention", "egnn"])
@pytest.mark.parametrize("case", ["coincident particles", "huge velocities", "single particle", "dense cluster"])
def test_other_processors_stay_finite(processor, case):
    simulator = tiny_simulator(REGISTRY, 2, processor)
    outcome = check_finite(simulator, CASES[case](2, torch.Generator().manual_seed(1)), torch.bfloat16)
    assert outcome.finite, outcome.failures


@pytest.mark.parametrize("dim", [2, 3])
def test_zero_standard_deviation_is_replaced_by_one(dim):
    simulator = tiny_simulator(REGISTRY, dim, zero_std=True)
    assert torch.equal(simulator.output_stats.std, torch.ones(dim))
    assert torch.equal(simulator.features.velocity_stats.std, torch.ones(dim))
    outcome = check_finite(simulator, CASES["coincident particles"](dim, torch.Generator().manual_seed(0)))
    assert outcome.finite, outcome.failures


def test_dense_cluster_keeps_every_neighbour():
    outcome = check_finite(tiny_simulator(REGISTRY, 3), CASES["dense cluster"](3, torch.Generator().manual_seed(0)))
    assert outcome.max_neighbours == 300 and outcome.num_edges == 300 * 300


def test_plain_vector_norm_has_a_nan_second_derivative_at_zero():
    # Why safe_norm exists: the self-edge of every particle has length 0.
    x = torch.zeros(1, 2, requires_grad=True)
    (first,) = torch.autograd.grad(torch.linalg.vector_norm(x, dim=-1).sum(), x, create_graph=True)
    (second,) = torch.autograd.grad(first.sum(), x)
    assert torch.isnan(second).all()


def test_safe_norm_derivatives_at_zero_are_zero():
    x = torch.zeros(3, 3, requires_grad=True)
    (first,) = torch.autograd.grad(safe_norm(x).sum(), x, create_graph=True)
    (second,) = torch.autograd.grad((first**2).sum() + first.sum(), x)
    assert torch.equal(first, torch.zeros(3, 3)) and torch.equal(second, torch.zeros(3, 3))


components = st.one_of(st.just(0.0), st.floats(-(2.0**100), 2.0**100, width=32))


@settings(max_examples=60, deadline=None)
@given(arrays("float32", (8, 3), elements=components))
def test_safe_norm_values_are_those_of_vector_norm(vectors):
    x = torch.from_numpy(vectors)
    assert torch.equal(safe_norm(x), torch.linalg.vector_norm(x, dim=-1, keepdim=True))
    y = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(safe_norm(y).sum(), y)
    reference = x.clone().requires_grad_(True)
    (expected,) = torch.autograd.grad(torch.linalg.vector_norm(reference, dim=-1).sum(), reference)
    assert torch.equal(grad, expected)
