"""The model predicts the velocity over the next frame; positions follow by one Euler step."""

from __future__ import annotations

from torch import Tensor

from gns_framework.contracts import Integrator


class VelocityEuler(Integrator):
    """``p[t+1] = p[t] + v[t+1]`` where ``v[t+1]`` is the predicted velocity (dt = 1 frame).

    The decoder's output is normalised with the velocity statistics. The exact
    inverse is ``v[t+1] = p[t+1] - p[t]``.

    Stability: first order in time and with no dynamics of its own (the next
    position does not depend on earlier velocities except through the model), so
    the integrator cannot blow up; a one-step error ``e`` moves the particle by ``e``
    and rollout errors accumulate like a random walk. The model must learn inertia
    itself, and the target scale is the velocity's, not the (much smaller)
    acceleration's. No physical ``advance``: it needs a velocity law, not a force law.
    """

    name = "velocity_euler"
    predicts = "velocity"

    def next_position(self, position_sequence: Tensor, prediction: Tensor) -> Tensor:
        return position_sequence[:, -1] + prediction

    def target(self, position_sequence: Tensor, next_position: Tensor) -> Tensor:
        return next_position - position_sequence[:, -1]
