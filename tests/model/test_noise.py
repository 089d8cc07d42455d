"""Random-walk training noise: a noise-free first position, and the last velocity's std is the one asked for."""

from __future__ import annotations

import pytest
import torch

from gns_framework.config.recipe import ModelSpec
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.model.noise import random_walk_noise, training_noise_std


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
