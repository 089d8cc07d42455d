"""A captured step (runtime/capture.py), emulated on the CPU as a CUDA graph behaves: replays rerun the recorded
operations on the recorded tensors and not the Python code; read-backs and host data are refused during capture."""

from __future__ import annotations

import pytest
import torch

from gns_framework.runtime.capture import CapturedStep, CaptureError
from gns_framework.runtime.host_sync import avoids_read_backs

CPU = torch.device("cpu")


def test_a_replay_reads_what_the_inputs_hold_now_and_rewrites_the_same_outputs():
    x = torch.zeros(4)
    total = torch.zeros(4)

    def step():
        y = torch.relu(x * 2 - 1)
        total.add_(y)  # state kept in a tensor, updated in place: a replay updates it again
        return y.sum(), total

    captured = CapturedStep(step, CPU, warmup=0)
    outputs = captured.outputs
    x.copy_(torch.tensor([0.0, 1.0, 2.0, 3.0]))
    s, t = captured()
    assert s is outputs[0] and t is total  # the same tensors every replay
    assert s.item() == 1.0 + 3.0 + 5.0 and t.tolist() == [0.0, 1.0, 3.0, 5.0]
    x.fill_(1.0)
    s, t = captured()
    assert s.item() == 4.0 and t.tolist() == [1.0, 2.0, 4.0, 6.0] and captured.replays == 2


def test_python_decisions_are_frozen_at_capture_as_on_a_gpu():
    # A step that branches in Python on a counter replays the branch it took at capture: the emulation
    # does not rerun Python, so a step that only works eagerly fails on the CPU as it would on a GPU.
    x = torch.ones(2)
    calls = []

    def step():
        calls.append(1)
        return x * len(calls)

    captured = CapturedStep(step, CPU, warmup=1)
    assert len(calls) == 2
    assert captured().tolist() == [2.0, 2.0] and captured().tolist() == [2.0, 2.0] and len(calls) == 2


@pytest.mark.parametrize(
    "step, refusal",
    [
        (lambda x: x[x > 0], "reads back"),
        (lambda x: x.sum().item(), "reads back"),
        (lambda x: x + torch.tensor([1.0, 2.0]), "host data"),
    ],
    ids=["boolean mask", "item", "torch.tensor"],
)
def test_what_a_cuda_graph_cannot_capture_is_refused_naming_the_line(step, refusal):
    x = torch.ones(2)
    with pytest.raises(CaptureError, match=refusal) as error:
        CapturedStep(lambda: step(x), CPU, warmup=0)
    assert "tests/runtime/test_capture.py:" in str(error.value)


def test_the_cpu_stands_in_for_an_accelerator_during_capture_only():
    seen = []
    CapturedStep(lambda: seen.append(avoids_read_backs(CPU)) or torch.zeros(1), CPU, warmup=1)
    assert seen == [True, True] and not avoids_read_backs(CPU)
