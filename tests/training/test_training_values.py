"""The training loop's parts against hand-computed values: random-walk noise, learning-rate schedules,
the optimiser and the trainer's loss (kinematic masking, multi-process scaling).

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

from gns_framework.config.recipe import OptimizerSpec
from gns_framework.model.noise import random_walk_noise
from gns_framework.training.distributed import Processes
from gns_framework.training.optim import learning_rate, make_optimizer

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


# --- learning-rate schedules ---------------------------------------------------------------------


EXPONENTIAL = OptimizerSpec(schedule="exponential", lr_init=1e-3, lr_min=1e-5, lr_decay=0.1, lr_decay_steps=100)
EXPONENTIAL_WARM = OptimizerSpec(
    schedule="exponential",
    lr_init=1e-3,
    lr_min=1e-5,
    lr_decay=0.1,
    lr_decay_steps=100,
    warmup_steps=10,
)
COSINE = OptimizerSpec(schedule="cosine", lr_init=1e-3, lr_min=1e-5, warmup_steps=10)


@pytest.mark.parametrize(
    ("spec", "step", "expected"),
    [
        # lr_min + (lr_init - lr_min) * 0.1 ** (step / 100)
        (EXPONENTIAL, 0, 1e-3),
        (EXPONENTIAL, 100, 1e-5 + 9.9e-4 * 0.1),  # 1.09e-4
        (EXPONENTIAL, 200, 1e-5 + 9.9e-4 * 0.01),  # 1.99e-5: the floor is half of it
        (EXPONENTIAL, 50, 1e-5 + 9.9e-4 / math.sqrt(10)),
        (EXPONENTIAL, 10**6, 1e-5),  # decays to the floor, never below
        # warm-up: lr_init * (step + 1) / warmup_steps, then the decay of the global step
        (EXPONENTIAL_WARM, 0, 1e-4),
        (EXPONENTIAL_WARM, 4, 5e-4),
        (EXPONENTIAL_WARM, 9, 1e-3),
        (EXPONENTIAL_WARM, 110, 1e-5 + 9.9e-4 * 0.1**1.1),
        # cosine over the 100 steps after warm-up of a 110-step run: lr_min + (lr_init - lr_min) (1 + cos(pi p)) / 2
        (COSINE, 0, 1e-4),
        (COSINE, 9, 1e-3),
        (COSINE, 10, 1e-3),
        (COSINE, 35, 1e-5 + 9.9e-4 * (1 + math.sqrt(0.5)) / 2),
        (COSINE, 60, 1e-5 + 9.9e-4 / 2),  # 5.05e-4
        (COSINE, 85, 1e-5 + 9.9e-4 * (1 - math.sqrt(0.5)) / 2),
        (COSINE, 110, 1e-5),
        (COSINE, 150, 1e-5),  # past the budget (a resumed run with more steps) it stays on the floor
    ],
)
def test_learning_rate_at_given_steps(spec, step, expected):
    assert learning_rate(spec, step, total_steps=110) == pytest.approx(expected, rel=1e-12)


def test_the_scheduler_sets_the_optimizers_rate_of_each_step():
    parameter = nn.Parameter(torch.zeros(1))
    optimizer, scheduler = make_optimizer([parameter], COSINE, total_steps=110)
    rates = []
    for _ in range(111):
        rates.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        scheduler.step()
    assert rates[0] == pytest.approx(1e-4, rel=1e-12)
    assert rates[60] == pytest.approx(5.05e-4, rel=1e-12)
    assert rates[110] == pytest.approx(1e-5, rel=1e-12)


# --- the optimiser -------------------------------------------------------------------------------


def test_optimizer_is_plain_adam_stepping_with_the_schedules_rate():
    """Two Adam steps by hand (beta1 0.9, beta2 0.999, eps 1e-8, no weight decay), the second at step 1's rate."""
    spec = OptimizerSpec(schedule="exponential", lr_init=1e-2, lr_min=1e-4, lr_decay=0.1, lr_decay_steps=1)
    start = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    parameter = nn.Parameter(start.clone())
    optimizer, scheduler = make_optimizer([parameter], spec, total_steps=10)
    g1 = torch.tensor([0.3, -0.1, 2.0], dtype=torch.float64)
    g2 = torch.tensor([-0.2, -0.4, 1.0], dtype=torch.float64)
    for gradient in (g1, g2):
        parameter.grad = gradient.clone()
        optimizer.step()
        scheduler.step()

    beta1, beta2, eps = 0.9, 0.999, 1e-8
    lr0, lr1 = 1e-2, 1e-4 + (1e-2 - 1e-4) * 0.1
    after_one = start - lr0 * g1 / (g1.abs() + eps)  # bias-corrected m / sqrt(v) = g / |g| on the first step
    m = beta1 * (1 - beta1) * g1 + (1 - beta1) * g2
    v = beta2 * (1 - beta2) * g1**2 + (1 - beta2) * g2**2
    expected = after_one - lr1 * (m / (1 - beta1**2)) / ((v / (1 - beta2**2)).sqrt() + eps)
    torch.testing.assert_close(parameter.detach(), expected, rtol=1e-12, atol=1e-15)
    assert optimizer.param_groups[0]["weight_decay"] == 0


def test_trainer_optimises_every_parameter_of_the_simulator_once(dataset_multimaterial, tmp_path):
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial), tmp_path)
    optimised = [id(p) for group in trainer.optimizer.param_groups for p in group["params"]]
    assert sorted(optimised) == sorted(id(p) for p in trainer.simulator.parameters())
    assert len(set(optimised)) == len(optimised)
    assert trainer.optimizer.param_groups[0]["lr"] == pytest.approx(trainer.recipe.training.optimizer.lr_init)
    trainer.close()


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

    def forward(self, batch, noise):
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
    batch = trainer.windows.batch(trainer.order.indices(0))
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
