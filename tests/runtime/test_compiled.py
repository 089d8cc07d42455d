"""The node side compiled with no graph breaks (runtime/compiled.py): ``fullgraph=True`` makes any break an error, so
tracing the step with the ``eager`` and ``aot_eager`` backends (the graphs inductor compiles, without generating code)
shows that the rollout and the training step, forward and backward, on the CPU path and the accelerators', compile
whole; and that a compiled model predicts what it did."""

from __future__ import annotations

import pytest
import torch
from fixed_capacity_cases import small_simulator, wandering_trajectory

from gns_framework.data.batch import collate, window
from gns_framework.model.rollout import rollout
from gns_framework.runtime.compiled import compile_node_side
from gns_framework.runtime.host_sync import EMULATED_ACCELERATOR

FUSED = {"name": "interaction_network", "message_passing_steps": 2, "edge_block": "fused"}


@pytest.fixture(autouse=True)
def fresh_compiles():
    torch._dynamo.reset()
    yield
    torch._dynamo.reset()


def test_the_node_side_is_what_the_components_declare():
    model = small_simulator("radius", FUSED)
    compiled = compile_node_side(model, backend="eager")
    assert compiled == [
        "encoder.node_mlp",
        "processor.steps.0.node_mlp",
        "processor.steps.1.node_mlp",
        "decoder",
        "features.node_features",
    ]


@pytest.mark.parametrize("processor", [FUSED, {"name": "shared_interaction_network", "message_passing_steps": 2}])
def test_a_compiled_rollout_predicts_the_eager_frames(processor):
    trajectory = wandering_trajectory(frames=10)
    eager = rollout(small_simulator("radius", processor), trajectory)
    model = small_simulator("radius", processor)
    compile_node_side(model, backend="eager")
    assert torch.equal(torch.from_numpy(rollout(model, trajectory).predicted), torch.from_numpy(eager.predicted))


@pytest.mark.parametrize("accelerator", [False, True])
def test_training_steps_of_two_sizes_compile_whole_forward_and_backward(accelerator):
    trajectory = wandering_trajectory(frames=12)
    batches = [collate([window(trajectory, k, 6) for k in starts]) for starts in ((0, 3), (1, 2, 4))]

    def loss_and_gradients(model, batch):
        for parameter in model.parameters():
            parameter.grad = None
        predicted, target = model(batch, torch.zeros_like(batch.position_sequence))
        loss = (predicted - target).square().mean()
        loss.backward()
        return [loss.detach()] + [p.grad for p in model.parameters() if p.grad is not None]

    token = EMULATED_ACCELERATOR.set(accelerator)
    try:
        eager = small_simulator("radius_fixed_capacity", FUSED).train()
        compiled = small_simulator("radius_fixed_capacity", FUSED).train()
        compile_node_side(compiled, backend="aot_eager")
        for batch in batches:  # dynamic shapes: the second size reuses the graphs
            for want, got in zip(loss_and_gradients(eager, batch), loss_and_gradients(compiled, batch), strict=True):
                assert torch.equal(want, got)
    finally:
        EMULATED_ACCELERATOR.reset(token)


def test_a_graph_break_on_the_node_side_is_an_error_naming_it():
    model = small_simulator("radius", FUSED)
    node_mlp = model.encoder.node_mlp
    plain_forward = node_mlp.forward

    def reads_a_value(x):
        if float(x.abs().max()) > 1e9:  # a read-back: the host decides on a value, the graph must break
            raise AssertionError
        return plain_forward(x)

    node_mlp.forward = reads_a_value
    compile_node_side(model, backend="eager")
    with pytest.raises(Exception, match=r"test_compiled\.py.*in reads_a_value"):
        rollout(model, wandering_trajectory(frames=8))


def test_a_compiled_node_side_can_be_captured_as_on_a_gpu():
    # gns rollout --compile --capture: on CUDA the compiled kernels are recorded in the CUDA graph; the CPU's
    # emulation records their operations run eagerly (compiled code cannot run under its recording mode).
    trajectory = wandering_trajectory(frames=12)
    eager = rollout(small_simulator("radius_fixed_capacity", FUSED), trajectory)
    model = small_simulator("radius_fixed_capacity", FUSED)
    compile_node_side(model, backend="eager")
    captured = rollout(model, trajectory, capture=True)
    # Captured, the fused edge block takes the accelerators' torch path: float32 rounding of positions ~0.5 m.
    assert float(abs(captured.predicted - eager.predicted).max()) <= 1e-5
