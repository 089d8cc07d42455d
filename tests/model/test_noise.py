"""Random-walk training noise: a noise-free first position, and the last velocity's std is the one asked for."""

from __future__ import annotations

import pytest
import torch

from gns_framework.config.recipe import ModelSpec
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.windows import WindowOrder
from gns_framework.model.noise import random_walk_noise, step_noise, training_noise_std, window_noise_generator


def test_the_first_position_is_noise_free_and_the_last_velocity_has_the_std_asked_for():
    history = torch.zeros(20000, 6, 2, dtype=torch.float64)
    noise = random_walk_noise(history, 0.01, torch.Generator().manual_seed(0))
    assert noise.shape == history.shape and noise.dtype == torch.float64
    assert torch.equal(noise[:, 0], torch.zeros(20000, 2, dtype=torch.float64))
    velocity = noise[:, 1:] - noise[:, :-1]
    # A random walk of 5 increments of std 0.01/sqrt(5): std 0.01 at the end, 0.01/sqrt(5) at the start.
    # 40,000 samples estimate a std to ~0.4 % (1/sqrt(2n)); 3 % fails a walk that is not one.
    assert velocity[:, -1].std().item() == pytest.approx(0.01, rel=0.03)
    assert velocity[:, 0].std().item() == pytest.approx(0.01 / 5**0.5, rel=0.03)


def test_the_same_generator_seed_gives_the_same_noise():
    history = torch.zeros(10, 4, 3)
    first = random_walk_noise(history, 0.1, torch.Generator().manual_seed(7))
    again = random_walk_noise(history, 0.1, torch.Generator().manual_seed(7))
    assert torch.equal(first, again)


def metadata(vel_std):
    return DatasetMetadata(
        bounds=[(0.0, 1.0), (0.0, 1.0)],
        sequence_length=10,
        default_connectivity_radius=0.1,
        dim=2,
        dt=0.01,
        vel_mean=[0.0, 0.0],
        vel_std=vel_std,
        acc_mean=[0.0, 0.0],
        acc_std=[1.0, 1.0],
    )


def test_the_noise_is_absolute_unless_it_is_relative_to_the_datas_velocities():
    assert training_noise_std(ModelSpec(noise_std=3e-4), metadata([1.0, 3.0])) == 3e-4
    assert training_noise_std(ModelSpec(noise_relative=0.1), metadata([1.0, 3.0])) == pytest.approx(0.2)


def test_every_window_of_a_step_has_its_own_stream_seeded_by_step_and_slot():
    one = [window_noise_generator(0, 5, slot).initial_seed() for slot in range(4)]
    assert len(set(one)) == 4, "every window of a step its own stream"
    assert window_noise_generator(0, 5, 2).initial_seed() == one[2]
    assert window_noise_generator(0, 6, 2).initial_seed() != one[2]


def test_one_process_of_w_windows_gets_the_noise_of_w_processes_of_one():
    particles = {0: 3, 1: 5, 2: 2, 3: 4}  # window -> particles; the order deals windows 0..3 in some order
    alone = WindowOrder(4, 4, seed=0).draw(0)
    whole = step_noise(alone, [particles[w] for w in alone.mine], (6, 2), 0.1, seed=9)
    ranks = [WindowOrder(4, 2, seed=0, rank=r, world_size=2).draw(0) for r in range(2)]
    shares = [step_noise(d, [particles[w] for w in d.mine], (6, 2), 0.1, seed=9) for d in ranks]
    assert ranks[0].every == alone.every
    assert torch.equal(torch.cat(shares), whole) and whole.shape == (14, 6, 2)
    again = step_noise(WindowOrder(4, 4, seed=0).draw(1), [3, 5, 2, 4], (6, 2), 0.1, seed=9)
    assert not torch.equal(again, whole)  # another step, other noise
