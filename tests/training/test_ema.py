"""The weight average: the exponential average of the weights by hand, state round trip, first update copies."""

from __future__ import annotations

import pytest
import torch

from gns_framework.training.ema import WeightAverage


def test_the_average_follows_the_recursion_and_leaves_the_model_alone():
    model = torch.nn.Linear(3, 2)
    average = WeightAverage(model, decay=0.9)
    history = []
    for step in range(5):
        with torch.no_grad():
            model.weight.add_(step + 1.0)
        history.append(model.weight.detach().clone())
        average.update(model)
    expected = history[0].double()
    for weights in history[1:]:
        expected = 0.9 * expected + 0.1 * weights.double()
    torch.testing.assert_close(average.module.weight.double(), expected, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(model.weight, history[-1])
    assert not torch.allclose(average.module.weight, model.weight)


def test_state_round_trip_resumes_the_same_average():
    model = torch.nn.Linear(3, 2)
    first = WeightAverage(model, decay=0.99)
    for _ in range(3):
        with torch.no_grad():
            model.weight.mul_(1.1)
        first.update(model)
    second = WeightAverage(torch.nn.Linear(3, 2), decay=0.99)
    second.load_state_dict(first.state_dict())
    with torch.no_grad():
        model.weight.add_(1.0)
    first.update(model)
    second.update(model)
    assert torch.equal(first.module.weight, second.module.weight)
    assert first.state_dict()["updates"] == 4


@pytest.mark.parametrize("decay", [0.0, 1.0, -0.5])
def test_a_decay_outside_the_open_interval_is_refused(decay):
    with pytest.raises(ValueError, match="ema_decay must lie in"):
        WeightAverage(torch.nn.Linear(1, 1), decay)
