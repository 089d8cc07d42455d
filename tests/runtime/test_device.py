"""One device policy for the model and the MPM: auto, cpu, cuda[:N], checked against what the backend sees."""

from __future__ import annotations

import pytest
import torch

from gns_framework.errors import GnsError
from gns_framework.runtime.device import choose_device, is_cuda, resolve_device, synchronize


@pytest.mark.parametrize(
    "name, count, chosen",
    [("auto", 0, "cpu"), ("auto", 2, "cuda:0"), ("cpu", 2, "cpu"), ("cuda", 1, "cuda:0"), ("cuda:1", 2, "cuda:1")],
)
def test_a_device_is_chosen_from_what_the_backend_sees(name, count, chosen):
    assert choose_device(name, lambda: count) == chosen


@pytest.mark.parametrize(
    "name, count, message",
    [
        ("cuda", 0, "training.device 'cuda': no CUDA device is available on this machine (use cpu or auto)"),
        ("cuda:2", 2, "training.device 'cuda:2': this machine has 2 CUDA devices (cuda:0 to cuda:1)"),
        ("gpu0", 1, "training.device 'gpu0': not a device: expected auto, cpu, cuda or cuda:N"),
        ("meta", 1, "training.device 'meta': not supported: expected auto, cpu, cuda or cuda:N"),
    ],
)
def test_a_device_the_machine_lacks_is_one_line_naming_the_field(name, count, message):
    with pytest.raises(GnsError) as error:
        choose_device(name, lambda: count, "training.device")
    assert str(error.value) == message


def test_the_models_device_is_a_torch_device():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")


@pytest.mark.parametrize(
    "device, cuda",
    [
        ("cpu", False),
        (torch.device("cpu"), False),
        (None, False),
        ("cuda", True),
        ("cuda:1", True),
        (torch.device("cuda", 0), True),
        ("meta", False),
    ],
)
def test_one_predicate_says_whether_a_device_is_cuda(device, cuda):
    assert is_cuda(device) is cuda


def test_synchronize_waits_only_on_cuda(monkeypatch):
    waited = []
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: waited.append(device))
    synchronize("cpu")
    synchronize(None)
    assert waited == []
    synchronize("cuda:0")
    assert waited == ["cuda:0"]
