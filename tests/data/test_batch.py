"""Training windows and batches: window cuts a trajectory into (N, C, d) inputs and its labels; collate stacks
examples keeping them apart; a batch moves to a device whole."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gns_framework.data.batch import ParticleBatch, collate, window
from gns_framework.data.trajectory import Trajectory

T, N, D = 10, 3, 2


def _trajectory(**fields) -> Trajectory:
    """Positions that encode their own indices: position[t, i] = (t, 10 i), so a misplaced frame shows."""
    t, i = np.meshgrid(np.arange(T), np.arange(N), indexing="ij")
    position = np.stack([t, 10 * i], axis=-1).astype(np.float32)
    base = dict(
        position=position,
        particle_type=np.array([5, 5, 3]),
        key="t",
        bounds=np.array([[-1.0, 20.0], [-1.0, 30.0]]),
        walls=np.array([[0.3, 0], [0.0, 0], [0.5, 0], [0.0, 1]]),
    )
    return Trajectory(**{**base, **fields}).validated("data")


def test_a_window_is_particle_major_history_with_the_next_frame_as_label():
    example = window(_trajectory(), start=2, history=4)
    assert example.position_sequence.shape == (N, 4, D) and example.num_examples == 1
    # Particle i's c-th position is frame start + c.
    assert example.position_sequence[:, :, 0].tolist() == [[2.0, 3.0, 4.0, 5.0]] * N
    assert example.position_sequence[:, 0, 1].tolist() == [0.0, 10.0, 20.0]
    assert example.next_position[:, 0].tolist() == [6.0] * N
    assert example.batch.tolist() == [0] * N and example.particle_type.tolist() == [5, 5, 3]
    assert example.ahead is None and example.material_property is None and example.context is None


def test_a_window_without_target_has_no_labels():
    example = window(_trajectory(), start=6, history=4, with_target=False)  # frames 6..9: the last four
    assert example.next_position is None and example.ahead is None
    assert example.position_sequence[0, :, 0].tolist() == [6.0, 7.0, 8.0, 9.0]


def test_ahead_keeps_the_true_frames_after_the_label():
    example = window(_trajectory(), start=1, history=3, ahead=2)
    assert example.next_position[0, 0] == 4.0
    assert example.ahead.shape == (N, 2, D) and example.ahead[:, :, 0].tolist() == [[5.0, 6.0]] * N
    # Without a target there is nothing ahead of it either.
    assert window(_trajectory(), start=1, history=3, with_target=False, ahead=2).ahead is None


def test_the_context_is_that_of_the_last_input_frame():
    context = np.arange(T, dtype=np.float32)[:, None] * np.array([[1.0, -1.0]], np.float32)
    example = window(_trajectory(step_context=context), start=3, history=4)
    assert example.context.tolist() == [[6.0, -6.0]]  # frame 3 + 4 - 1, one row for the one example


def test_the_material_property_and_the_domain_come_along():
    example = window(_trajectory(material_property=np.array([0.5, 0.7, 0.0])), start=0, history=2)
    torch.testing.assert_close(example.material_property, torch.tensor([[0.5], [0.7], [0.0]]))
    assert example.bounds.shape == (1, D, 2) and example.walls.shape == (1, 2 * D, 2)
    assert example.walls[0, 3, 1] == 1.0


def test_collate_numbers_the_examples_of_already_stacked_batches_in_turn():
    one = window(_trajectory(), 0, 4)
    two = collate([window(_trajectory(), 1, 4), window(_trajectory(), 2, 4)])
    batch = collate([one, two])
    assert batch.num_examples == 3 and batch.num_particles == 3 * N
    assert batch.batch.tolist() == [0] * N + [1] * N + [2] * N
    assert batch.position_sequence[:, 0, 0].tolist() == [0.0] * N + [1.0] * N + [2.0] * N
    assert batch.next_position.shape == (3 * N, D) and batch.bounds.shape == (3, D, 2)
    assert batch.context is None and batch.ahead is None


def test_examples_with_and_without_their_own_domain_do_not_mix():
    with_domain = window(_trajectory(), 0, 6)
    without = window(_trajectory(bounds=None, walls=None), 0, 6)
    with pytest.raises(ValueError, match="some examples have bounds and some not"):
        collate([with_domain, without])


def test_examples_without_a_domain_collate_to_none():
    bare = [window(_trajectory(bounds=None, walls=None), s, 4) for s in (0, 1)]
    batch = collate(bare)
    assert batch.bounds is None and batch.walls is None


def test_to_moves_every_tensor_and_leaves_missing_fields_missing():
    batch = window(_trajectory(), 0, 4)
    moved = batch.to("meta")
    assert isinstance(moved, ParticleBatch) and moved.num_examples == 1
    for name in ("position_sequence", "particle_type", "batch", "next_position", "bounds", "walls"):
        assert getattr(moved, name).device.type == "meta", name
        assert getattr(batch, name).device.type == "cpu", name  # the original batch stays where it was
    assert moved.context is None and moved.ahead is None and moved.material_property is None
