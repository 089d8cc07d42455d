"""The differentiable learned rollout (``gns_framework.inverse.rollout``): the frames it predicts are those of the
model stepped one frame at a time, and gradient checkpointing (any segment length, the last segment shorter)
changes neither the loss nor its gradient. The shipped model in float64, so equal means equal to ~1e-12."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from inverse_cases import problem_of

from gns_framework.inverse.rollout import differentiable_rollout
from gns_framework.model.history import advance_window


def test_checkpointing_gives_the_same_loss_and_gradient(shipped_float64, observed):
    whole, checkpointed = (problem_of(shipped_float64, observed, "positions", k) for k in (0, 2))
    results = []
    for problem in (whole, checkpointed):
        u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
        loss = problem.loss(u)
        results.append((loss.item(), torch.autograd.grad(loss, u)[0].numpy()))
    assert results[0][0] == pytest.approx(results[1][0], rel=1e-12)
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=1e-10)


def stepped(simulator, state, prescribed):
    """The reference: one model step per frame, the input window moved on by each prediction."""
    sequence, frames = state.position_sequence, []
    for next_prescribed in prescribed:
        position = simulator.predict_next_position(
            replace(state, position_sequence=sequence), prescribed=next_prescribed
        )
        frames.append(position)
        sequence = advance_window(sequence, position)
    return torch.stack(frames)


@pytest.mark.parametrize("checkpoint_every", [0, 1, 4, 6, 10])
def test_every_segmentation_predicts_the_frames_of_single_steps(shipped_float64, observed, checkpoint_every):
    problem = problem_of(shipped_float64, observed, "positions", frames=(11,))
    u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
    state = problem.model_inputs(u)
    assert problem.prescribed.shape[0] == 6  # frames 6 .. 11: with K = 4, segments of 4 and 2 steps
    predicted = differentiable_rollout(shipped_float64, state, problem.prescribed, checkpoint_every)
    with torch.no_grad():
        expected = stepped(shipped_float64, state, problem.prescribed)
    assert predicted.shape == expected.shape == problem.prescribed.shape
    # The same float64 operations in the same order, recomputed or not: equal to round-off of positions ~0.5.
    torch.testing.assert_close(predicted.detach(), expected, rtol=0, atol=1e-12)
    (gradient,) = torch.autograd.grad(predicted[-1].square().sum(), u)
    whole = problem.model_inputs(u)
    (reference,) = torch.autograd.grad(
        differentiable_rollout(shipped_float64, whole, problem.prescribed)[-1].square().sum(), u
    )
    assert gradient.abs().min() > 0, "every unknown moves the last frame"
    np.testing.assert_allclose(gradient.numpy(), reference.numpy(), rtol=1e-10)


@pytest.mark.parametrize("checkpoint_every", [0, 4])
def test_walls_hold_as_in_gns_rollout_and_gradients_still_flow(shipped_float64, observed, checkpoint_every):
    """With the model's guard (clamp), the differentiable rollout puts escaped particles back as the inference
    rollout does (issue 46): equal frames, none beyond a wall, and a finite gradient for every unknown."""
    from gns_framework.config.recipe import RolloutGuardSpec
    from gns_framework.model.rollout_guard import RolloutGuard

    problem = problem_of(shipped_float64, observed, "positions", frames=(11,))
    u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
    state = problem.model_inputs(u)
    first = state.position_sequence[:, -1].detach()
    # Walls just inside the cloud: particles pass them at every step and are put back.
    walls = torch.stack([first.min(0).values + 0.01, first.max(0).values - 0.01], dim=1).numpy()
    guard = RolloutGuard.from_spec(shipped_float64.setup, RolloutGuardSpec(margin=0.0, on_violation="clamp"))
    guard = guard.with_bounds(walls)
    predicted = differentiable_rollout(shipped_float64, state, problem.prescribed, checkpoint_every, guard)
    sequence, frames = state.position_sequence.detach(), []
    with torch.no_grad():
        for next_prescribed in problem.prescribed:
            position = shipped_float64.predict_next_position(
                replace(state, position_sequence=sequence), prescribed=next_prescribed
            )
            position, _ = guard.check(len(frames), position, sequence[:, -1])
            frames.append(position)
            sequence = advance_window(sequence, position)
    moving = problem.moving
    torch.testing.assert_close(predicted.detach()[:, moving], torch.stack(frames)[:, moving], rtol=0, atol=1e-12)
    lower, upper = torch.as_tensor(walls[:, 0]), torch.as_tensor(walls[:, 1])
    assert ((predicted[:, moving] >= lower - 1e-12) & (predicted[:, moving] <= upper + 1e-12)).all()
    (gradient,) = torch.autograd.grad(predicted[-1].square().sum(), u)
    assert torch.isfinite(gradient).all() and gradient.abs().max() > 0
