"""Learning-rate schedules and the optimiser against hand-computed values (training/optim.py)."""

from __future__ import annotations

import math

import pytest
import torch
from tiny import tiny_recipe, tiny_trainer
from torch import nn

from gns_framework.config.recipe import OptimizerSpec
from gns_framework.training.optim import learning_rate, make_optimizer

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # restores the count the tiny trainer sets to 1


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
# The same cosine compressed into the first half of the run: floor at step round(0.5 * 110) = 55.
COSINE_HALF = OptimizerSpec(schedule="cosine", lr_init=1e-3, lr_min=1e-5, warmup_steps=10, anneal_fraction=0.5)


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
        # anneal_fraction 0.5: the half cosine spans steps 10..55 (45 steps), then the floor
        (COSINE_HALF, 9, 1e-3),
        (COSINE_HALF, 10 + 45 / 2, 1e-5 + 9.9e-4 / 2),
        (COSINE_HALF, 55, 1e-5),
        (COSINE_HALF, 80, 1e-5),
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
