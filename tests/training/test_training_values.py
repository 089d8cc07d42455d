"""The training loop's parts against hand-computed values: random-walk noise and the trainer's loss
(kinematic masking, multi-process scaling); the schedules and the optimiser are in test_optim.py.

The parity harness (parity/) brings its own noise, loss and Adam, so these are the
project's only checks of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
import torch
from tiny import tiny_recipe, tiny_trainer
from torch import nn

from gns_framework.model.noise import random_walk_noise
from gns_framework.runtime.processes import Processes

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # restores the count the tiny trainers set to 1

KINEMATIC_TYPE = 3
"""The synthetic datasets' floor particles (tests/synthetic.py), kinematic in the built-in materials."""


# --- random-walk noise ---------------------------------------------------------------------------


def test_random_walk_noise_has_the_hand_computed_std_at_every_history_step():
    """Velocity noise v_j = e_1 + ... + e_j with e_i ~ N(0, sigma^2 / (C - 1)): std sigma sqrt(j / (C - 1)),
    sigma at the last velocity. Position noise p_k = v_1 + ... + v_k: variance
    sigma^2 / (C - 1) * sum_{i<=k} (k - i + 1)^2 = sigma^2 / (C - 1) * k (k + 1) (2k + 1) / 6; p_0 = 0."""
    sigma, n, c, d = 0.01, 100_000, 6, 2
    noise = random_walk_noise(torch.zeros(n, c, d, dtype=torch.float64), sigma, torch.Generator().manual_seed(0))
    assert noise.shape == (n, c, d) and noise.dtype == torch.float64
    assert torch.equal(noise[:, 0], torch.zeros(n, d))

    samples = n * d
    tolerance = 5 / math.sqrt(2 * samples)  # 5 standard errors of a sample std, relative
    velocity = noise.diff(dim=1)
    for j in range(1, c):
        expected = sigma * math.sqrt(j / (c - 1))
        assert velocity[:, j - 1].std().item() == pytest.approx(expected, rel=tolerance), f"velocity {j}"
    assert velocity[:, -1].std().item() == pytest.approx(sigma, rel=tolerance)
    for k in range(1, c):
        expected = sigma * math.sqrt(k * (k + 1) * (2 * k + 1) / 6 / (c - 1))
        assert noise[:, k].std().item() == pytest.approx(expected, rel=tolerance), f"position {k}"

    first, second_increment = velocity[:, 0].flatten(), (velocity[:, 1] - velocity[:, 0]).flatten()
    correlation = torch.corrcoef(torch.stack([first, second_increment]))[0, 1].item()
    assert abs(correlation) < 5 / math.sqrt(samples), "the walk's increments are independent"


def test_random_walk_noise_keeps_dtype_and_draws_from_the_generator():
    shape = torch.zeros(7, 4, 3, dtype=torch.float32)
    first = random_walk_noise(shape, 0.1, torch.Generator().manual_seed(5))
    again = random_walk_noise(shape, 0.1, torch.Generator().manual_seed(5))
    assert first.dtype == torch.float32 and torch.equal(first, again)
    assert not torch.equal(first, random_walk_noise(shape, 0.1, torch.Generator().manual_seed(6)))


# --- the trainer's loss --------------------------------------------------------------------------


class FixedPrediction(nn.Module):
    """Stands in for the model: predicts ``offset`` for every particle against a fixed target, and keeps
    the noise it was given."""

    def __init__(self, dim: int):
        super().__init__()
        self.offset = nn.Parameter(torch.zeros(dim, dtype=torch.float32))
        self.noise = None

    @staticmethod
    def target(num_particles: int, dim: int) -> torch.Tensor:
        return torch.arange(num_particles * dim, dtype=torch.float32).reshape(num_particles, dim) / 10

    def forward(self, batch, noise, unrolled_steps=0):
        self.noise = noise.clone()
        num_particles, dim = batch.num_particles, batch.position_sequence.shape[-1]
        return self.offset.expand(num_particles, dim), self.target(num_particles, dim)


@dataclass(frozen=True)
class TwoProcesses(Processes):
    """Rank 0 of 2, whose partner contributes ``other`` = (error sum, predicted particles)."""

    other: tuple[float, float] = (0.0, 0.0)

    def sum(self, tensor):
        return tensor + torch.tensor(self.other, dtype=tensor.dtype)


@pytest.mark.parametrize("other", [None, (50.0, 30.0)], ids=["one process", "rank 0 of two"])
def test_trainer_loss_masks_kinematic_particles_and_scales_for_the_world(dataset_multimaterial, tmp_path, other):
    """loss = (sum over predicted particles of |prediction - target|^2) * W / (predicted particles of all ranks):
    DDP's mean over W ranks makes it the global batch's mean. The returned loss is the global one; the particle
    count is that of the step's global windows, known to every rank from the window order without communication
    (here the order is one process's, so it is this batch's)."""
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial), tmp_path)
    batch = trainer.windows.batch(trainer.order.draw(0).mine)
    kinematic = batch.particle_type == KINEMATIC_TYPE
    assert 0 < kinematic.sum() < batch.num_particles
    stub = FixedPrediction(batch.position_sequence.shape[-1])
    trainer.optimisation.model = stub
    world_size = 1
    if other is not None:
        trainer.optimisation.processes, world_size = TwoProcesses(world_size=2, other=other), 2
    other = other or (0.0, 0.0)

    loss, particles = trainer.train_step()

    target = FixedPrediction.target(batch.num_particles, batch.position_sequence.shape[-1]).double()
    predicted = ~kinematic
    error_sum = (target[predicted] ** 2).sum().item()  # the prediction is 0 (offset 0)
    all_predicted = predicted.sum().item() + other[1]
    assert loss == pytest.approx((error_sum + other[0]) / all_predicted, rel=1e-6)
    assert particles == batch.num_particles
    # d loss / d offset = 2 W / (all predicted) * sum over predicted particles of (offset - target)
    expected_gradient = -2 * world_size / all_predicted * target[predicted].sum(dim=0)
    torch.testing.assert_close(stub.offset.grad.double(), expected_gradient, rtol=1e-5, atol=0)

    # The noise of kinematic particles is zero (their motion is prescribed); every other particle's is not.
    assert stub.noise.shape == batch.position_sequence.shape
    assert torch.equal(stub.noise[kinematic], torch.zeros_like(stub.noise[kinematic]))
    assert (stub.noise[predicted][:, 1:].abs() > 0).all()
    trainer.close()
