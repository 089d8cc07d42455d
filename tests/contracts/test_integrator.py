"""The integrator contract: next_position and target are both required; the defaults of its class facts."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Integrator, Params


def test_next_position_and_its_inverse_are_both_required():
    class ForwardOnly(Integrator):
        name = "forward_only"

        def next_position(self, position_sequence, prediction):
            return position_sequence[:, -1] + prediction

    class InverseOnly(Integrator):
        name = "inverse_only"

        def target(self, position_sequence, next_position):
            return next_position - position_sequence[:, -1]

    with pytest.raises(TypeError, match="abstract method target"):
        ForwardOnly(Params())
    with pytest.raises(TypeError, match="abstract method next_position"):
        InverseOnly(Params())


class Drift(Integrator):
    """p[t+1] = p[t] + v: the prediction is a velocity."""

    name = "drift"
    predicts = "velocity"

    def next_position(self, position_sequence, prediction):
        return position_sequence[:, -1] + prediction

    def target(self, position_sequence, next_position):
        return next_position - position_sequence[:, -1]


def test_an_integrator_keeps_its_params():
    class Scaled(Params):
        factor: float = 1.0

    assert Drift(Scaled(factor=2.0)).params.factor == 2.0


def test_the_defaults_say_acceleration_with_no_physical_form():
    class Plain(Drift):
        predicts = Integrator.predicts

    assert Plain.predicts == "acceleration"
    # No advance: neither symplectic nor with a stability bound, and no twin position map.
    assert Plain.symplectic is False and Plain.stability_bound is None and Plain.same_position_map_as is None


def test_a_subclass_inverts_its_own_map():
    integrator = Drift(Params())
    history = torch.tensor([[[0.0, 0.0], [0.1, 0.2]]])  # (N=1, C=2, d=2)
    prediction = torch.tensor([[0.05, -0.1]])
    reached = integrator.next_position(history, prediction)
    torch.testing.assert_close(integrator.target(history, reached), prediction)
