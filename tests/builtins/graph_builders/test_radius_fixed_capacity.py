"""The fixed-capacity radius builder: radius's edges in fixed-size buffers, padding joined to a sink node, and
models and rollouts that give what they give with ``radius`` (overflows redone, never silent).

The search itself is tested in tests/builtins/_kernels/test_padded_cell_list.py, its sizing in
tests/builtins/_kernels/test_fixed_capacity.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fixed_capacity_cases import SETUP, small_simulator, wandering_trajectory

from gns_builtins.graph_builders.radius import RadiusGraphBuilder
from gns_builtins.graph_builders.radius_fixed_capacity import FixedCapacityRadiusGraphBuilder
from gns_framework.data.batch import ParticleBatch
from gns_framework.model.rollout import rollout
from gns_framework.runtime.sync_counter import SyncCounter


def _cloud(n=300, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=generator), torch.zeros(n, dtype=torch.long)


def test_the_edges_are_radius_edges_then_padding_between_sinks():
    position, batch = _cloud()
    exact = RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP).build(position, batch, 1)
    builder = FixedCapacityRadiusGraphBuilder(FixedCapacityRadiusGraphBuilder.Params(capacity=1.5), SETUP)
    graph = builder.build(position, batch, 1)
    count = exact.num_edges
    assert graph.num_edges == int(np.ceil(1.5 * count)) and graph.num_nodes == 301
    assert torch.equal(graph.senders[:count], exact.senders) and torch.equal(graph.receivers[:count], exact.receivers)
    assert torch.equal(graph.displacement[:count], exact.displacement)
    assert (graph.senders[count:] == 300).all() and (graph.receivers[count:] == 300).all()
    assert (graph.displacement[count:] == 0).all()
    assert graph.node_particle.tolist() == [*range(300), 299]  # the sink takes the last particle's features


def test_on_an_accelerator_the_indices_are_int32_and_the_same_edges():
    # Issue 45, item 4: a GPU step gathers node rows by these in every message-passing step; int32 halves that.
    from gns_framework.runtime.host_sync import EMULATED_ACCELERATOR

    position, batch = _cloud()
    params = FixedCapacityRadiusGraphBuilder.Params(capacity=1.5)
    on_cpu = FixedCapacityRadiusGraphBuilder(params, SETUP).build(position, batch, 1)
    token = EMULATED_ACCELERATOR.set(True)
    try:
        on_gpu = FixedCapacityRadiusGraphBuilder(params, SETUP).build(position, batch, 1)
    finally:
        EMULATED_ACCELERATOR.reset(token)
    assert on_cpu.senders.dtype == torch.int64 and on_gpu.senders.dtype == on_gpu.receivers.dtype == torch.int32
    assert torch.equal(on_gpu.senders.long(), on_cpu.senders) and torch.equal(on_gpu.receivers.long(), on_cpu.receivers)
    assert torch.equal(on_gpu.displacement, on_cpu.displacement)


def test_later_frames_of_a_scene_build_without_waiting_for_the_device():
    position, batch = _cloud()
    builder = FixedCapacityRadiusGraphBuilder(FixedCapacityRadiusGraphBuilder.Params(), SETUP)
    builder.checks_deferred = True  # as under a rollout
    builder.build(position, batch, 1)  # the first frame sizes the buffers: read-backs
    with SyncCounter() as counter:
        for k in range(3):
            builder.build(position + 0.001 * k, batch, 1)
    assert counter.counts == {}
    assert not builder.overflowed()


def test_an_overflow_is_found_at_the_check_and_the_buffers_grow():
    position, batch = _cloud()
    builder = FixedCapacityRadiusGraphBuilder(FixedCapacityRadiusGraphBuilder.Params(capacity=1.0), SETUP)
    builder.checks_deferred = True
    first = builder.build(position, batch, 1)
    squeezed = builder.build(0.5 + 0.8 * (position - 0.5), batch, 1)  # denser: more pairs than the buffers hold
    assert squeezed.num_edges == first.num_edges
    assert builder.overflowed() and not builder.overflowed()  # read once, then forgotten
    exact = RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP).build(0.5 + 0.8 * (position - 0.5), batch, 1)
    for _ in range(3):  # as a rollout does: redo until a check passes (the pairs' count was estimated)
        again = builder.build(0.5 + 0.8 * (position - 0.5), batch, 1)
        if not builder.overflowed():
            break
    else:
        pytest.fail("three rounds of growth did not fit the scene")
    assert again.num_edges > first.num_edges
    assert torch.equal(again.senders[: exact.num_edges], exact.senders)
    assert torch.equal(again.receivers[: exact.num_edges], exact.receivers)


def test_without_a_deferring_caller_each_build_is_checked_at_once():
    position, batch = _cloud()
    builder = FixedCapacityRadiusGraphBuilder(FixedCapacityRadiusGraphBuilder.Params(capacity=1.0), SETUP)
    builder.build(position, batch, 1)
    squeezed = 0.5 + 0.8 * (position - 0.5)
    graph = builder.build(squeezed, batch, 1)
    exact = RadiusGraphBuilder(RadiusGraphBuilder.Params(), SETUP).build(squeezed, batch, 1)
    assert torch.equal(graph.senders[: exact.num_edges], exact.senders)
    assert torch.equal(graph.receivers[: exact.num_edges], exact.receivers)
    assert (graph.receivers[exact.num_edges :] == 300).all()


PROCESSORS = [
    {"name": "interaction_network", "message_passing_steps": 2},
    {"name": "interaction_network", "message_passing_steps": 2, "edge_block": "plain"},
    {"name": "shared_interaction_network", "message_passing_steps": 2},
    {"name": "graph_attention", "message_passing_steps": 2},
    {"name": "egnn", "message_passing_steps": 2},
    {"name": "grid_cnn", "message_passing_steps": 2},  # the sink node must leave no trace on its grid
]


@pytest.mark.parametrize("processor", PROCESSORS, ids=lambda p: f"{p['name']}-{p.get('edge_block', '')}")
def test_a_model_predicts_what_it_predicts_on_the_exact_graph(processor):
    generator = torch.Generator().manual_seed(1)
    sequence = (0.2 + 0.6 * torch.rand(200, 1, 2, generator=generator)) + 0.002 * torch.randn(
        200, 6, 2, generator=generator
    ).cumsum(1)
    current = ParticleBatch(sequence, torch.full((200,), 5), torch.zeros(200, dtype=torch.long), 1)
    with torch.no_grad():
        exact_model, fixed_model = (
            small_simulator("radius", processor),
            small_simulator("radius_fixed_capacity", processor),
        )
        # The latents, O(1) after the processor's LayerNorms: a sink's trace shows here long before in positions.
        exact = exact_model.processed_latent(sequence, current)
        fixed = fixed_model.processed_latent(sequence, current)
        assert fixed.shape == exact.shape == (200, 8)
        torch.testing.assert_close(fixed, exact, rtol=0, atol=1e-5)  # float32 rounding of O(1) values
        positions = exact_model.predict_next_position(current), fixed_model.predict_next_position(current)
    torch.testing.assert_close(*positions, rtol=0, atol=1e-6)


def test_a_rollout_that_outgrows_its_buffers_redoes_those_steps_and_equals_the_exact_one():
    # An untrained model with large accelerations moves the particles far: with capacity 1.0 a later frame
    # needs more pairs than the first (the test checks it did), and the rollout must redo those steps.
    trajectory = wandering_trajectory()
    processor = {"name": "interaction_network", "message_passing_steps": 2}
    exact = rollout(small_simulator("radius", processor, acc_std=0.02), trajectory)
    model = small_simulator("radius_fixed_capacity", processor, acc_std=0.02)
    fixed = rollout(model, trajectory)
    assert model.graph_builder.search.sizings > 1, "the scene never outgrew its first buffers: make it"
    assert not model.graph_builder.checks_deferred  # the rollout hands the checks back
    np.testing.assert_allclose(fixed.predicted, exact.predicted, rtol=0, atol=1e-5)
