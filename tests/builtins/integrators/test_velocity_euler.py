"""Velocity Euler: the prediction is the next frame's displacement, whatever the earlier frames were."""

from __future__ import annotations

import torch

from gns_builtins.integrators.velocity_euler import VelocityEuler

INTEGRATOR = VelocityEuler(VelocityEuler.Params())


def test_next_position_is_the_last_position_plus_the_predicted_velocity():
    history = torch.tensor([[[0.1, 0.3], [0.25, 0.5]], [[2.0, 2.0], [1.0, -1.0]]], dtype=torch.float64)
    prediction = torch.tensor([[0.4, -0.2], [0.0, 0.5]], dtype=torch.float64)
    expected = torch.tensor([[0.65, 0.3], [1.0, -0.5]], dtype=torch.float64)
    torch.testing.assert_close(INTEGRATOR.next_position(history, prediction), expected, rtol=0, atol=1e-15)


def test_earlier_frames_do_not_move_the_particle():
    # No inertia in the integrator: only the last frame and the prediction count (the model must learn inertia).
    prediction = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    resting = torch.tensor([[[0.25, 0.5], [0.25, 0.5], [0.25, 0.5]]], dtype=torch.float64)
    moving = torch.tensor([[[-1.0, 3.0], [0.0, 1.0], [0.25, 0.5]]], dtype=torch.float64)
    torch.testing.assert_close(
        INTEGRATOR.next_position(moving, prediction), INTEGRATOR.next_position(resting, prediction)
    )


def test_target_is_the_displacement_over_the_next_frame():
    # A particle moving at constant velocity (0.15, 0.2) per frame: the target is that velocity, not 0 as an
    # acceleration.
    history = torch.tensor([[[0.1, 0.3], [0.25, 0.5]]], dtype=torch.float64)
    following = torch.tensor([[0.4, 0.7]], dtype=torch.float64)
    torch.testing.assert_close(
        INTEGRATOR.target(history, following), torch.tensor([[0.15, 0.2]], dtype=torch.float64), rtol=0, atol=1e-15
    )


def test_it_predicts_velocity_and_has_no_physical_form():
    # predicts picks the velocity statistics to normalise the decoder's output; without a force law there is no advance.
    assert VelocityEuler.predicts == "velocity"
    assert not hasattr(VelocityEuler, "advance") and VelocityEuler.stability_bound is None
