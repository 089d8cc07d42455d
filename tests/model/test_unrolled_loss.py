"""gns_framework.model.unrolled_loss: each unrolled step's output minus target is the model's own rollout's position
error against the truth, its first step is the one-step forward's, and the gradient flows through the rolled
frames."""

from __future__ import annotations

import torch
from test_learned_simulator import simulator

from gns_framework.data.batch import ParticleBatch


def unrolled_windows(n=12, history=6, ahead=3):
    """Windows with their next frame and ``ahead`` true frames after it, of smooth random paths."""
    generator = torch.Generator().manual_seed(2)
    start = 0.2 + 0.6 * torch.rand(n, 1, 2, generator=generator)
    path = start + 0.003 * torch.randn(n, history + 1 + ahead, 2, generator=generator).cumsum(1)
    types = torch.tensor([3, 5] * (n // 2))
    return ParticleBatch(
        path[:, :history],
        types,
        torch.zeros(n, dtype=torch.long),
        1,
        next_position=path[:, history],
        ahead=path[:, history + 1 :],
    )


def test_each_unrolled_steps_error_is_its_own_rollouts_position_error():
    # With the semi-implicit Euler step x' = 2x - x_prev + a, output minus target is the rolled position minus the
    # true one: the unrolled loss is the error of the model's own rollout, frame by frame.
    model, windows = simulator(), unrolled_windows()
    noise = 1e-3 * torch.randn(windows.position_sequence.shape, generator=torch.Generator().manual_seed(3))
    moving = model.predicted_mask(windows.particle_type)
    noise[~moving] = 0.0
    with torch.no_grad():
        prediction, target = model(windows, noise, 2)
    assert prediction.shape == target.shape == (3 * 12, 2)
    window, truths = windows.position_sequence + noise, [windows.next_position, *windows.ahead[:, :2].unbind(1)]
    for k, truth in enumerate(truths):
        with torch.no_grad():
            rolled = model.integrator.next_position(
                window, model.output_stats.denormalize(model.normalized_prediction(window, windows))
            )
        rows = slice(12 * k, 12 * (k + 1))
        error = model.output_stats.denormalize(prediction[rows]) - model.output_stats.denormalize(target[rows])
        torch.testing.assert_close(error[moving], (rolled - truth - noise[:, -1])[moving], rtol=1e-4, atol=1e-7)
        window = torch.cat([window[:, 1:], torch.where(moving[:, None], rolled, truth + noise[:, -1])[:, None]], 1)
    assert (rolled - truth)[moving].abs().max() > 1e-4, "the rollout drifts from the truth: the check has weight"
    first_only, _ = model(windows, noise)
    torch.testing.assert_close(first_only, prediction[:12], rtol=0, atol=0)


def test_the_unrolled_loss_has_gradient_through_the_rolled_frames():
    model, windows = simulator(), unrolled_windows()
    noise = torch.zeros_like(windows.position_sequence)
    prediction, target = model(windows, noise, 1)
    through = torch.autograd.grad(((prediction[12:] - target[12:]) ** 2).sum(), list(model.parameters()))
    # The same second step with the rolled frame cut from the graph: the values agree and the gradients do not.
    window = windows.position_sequence
    rolled = model.integrator.next_position(
        window, model.output_stats.denormalize(model.normalized_prediction(window, windows))
    ).detach()
    moving = model.predicted_mask(windows.particle_type)[:, None]
    cut = torch.cat([window[:, 1:], torch.where(moving, rolled, windows.next_position)[:, None]], 1)
    cut_prediction = model.normalized_prediction(cut, windows)
    cut_target = model.output_stats.normalize(model.integrator.target(cut, windows.ahead[:, 0]))
    torch.testing.assert_close(cut_prediction, prediction[12:])
    torch.testing.assert_close(cut_target, target[12:])
    without = torch.autograd.grad(((cut_prediction - cut_target) ** 2).sum(), list(model.parameters()))
    assert any(not torch.allclose(a, b) for a, b in zip(through, without, strict=True))
