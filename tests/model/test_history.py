"""advance_window: the oldest frame out, the new one in, for every particle alike."""

import torch

from gns_framework.model.history import advance_window


def test_the_window_moves_on_by_one_frame():
    # Particle p at frame t sits at (p, t): every entry says where it came from.
    frames = torch.arange(4.0)[None, :, None].expand(3, 4, 2) + 10 * torch.arange(3.0)[:, None, None]
    next_position = torch.full((3, 2), 99.0)
    moved = advance_window(frames, next_position)
    assert moved.shape == frames.shape
    assert torch.equal(moved[:, :-1], frames[:, 1:])
    assert torch.equal(moved[:, -1], next_position)
    assert torch.equal(frames[:, 0, 0], torch.tensor([0.0, 10.0, 20.0])), "the input window is left as it was"


def test_gradients_flow_to_the_new_frame_and_the_kept_ones():
    frames = torch.zeros(2, 3, 2, requires_grad=True)
    next_position = torch.zeros(2, 2, requires_grad=True)
    advance_window(frames, next_position).sum().backward()
    assert torch.equal(frames.grad[:, 0], torch.zeros(2, 2)), "the dropped frame no longer counts"
    assert torch.equal(frames.grad[:, 1:], torch.ones(2, 2, 2))
    assert torch.equal(next_position.grad, torch.ones(2, 2))
