"""One optimisation step: a batch of noisy training windows, push-forward, the loss, the backward and the update.

The model learns accelerations from windows of C past positions (Sanchez-Gonzalez et al. 2020). Two things make
what it learns hold over a long rollout, where its inputs are its own predictions:

- random-walk noise on the input positions (the target is corrected so that the next position stays the true
  one), so it learns to pull a drifted state back;
- push-forward (Brandstetter et al. 2022): the window is first rolled on k steps by the model itself, without
  gradient, and it learns the true frame after them (with an unrolled loss, ``model/unrolled_loss.py``, the K
  frames after that too, with gradient through them).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from torch import Tensor

from ..data.batch import ParticleBatch
from ..data.windows import WindowIndex, WindowOrder
from ..model.history import advance_window
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_squared_error_sum
from ..model.noise import step_noise
from ..runtime.device import is_cuda
from ..runtime.precision import Precision, autocast, backward_precision
from ..runtime.processes import Processes
from .ema import WeightAverage


class TrainingStep:
    """The optimisation step of a run, called once per step number.

    Args:
        simulator: the bare model (its predicted mask, its own push-forward rollouts).
        model: what the loss is taken through: ``simulator``, or its DDP wrapper,
            whose backward averages the gradients over the ranks.
        windows, order: the train split's windows and which of them each step and rank takes.
        noise_std: per-step standard deviation of the random-walk input noise (L).
        optimizer, scheduler: the update and its learning-rate schedule.
        ema: the weight average updated after every update, or None.
        processes: this process's place in a torchrun job.
        seed: the run's seed (noise and push-forward draws are seeded by it and the step).
        pushforward_steps: the most push-forward steps (0: none).
        unrolled_loss_steps: steps rolled on after the next frame with gradient, in the loss (0: one-step loss).
        precision: of the forward and backward (``training.precision``).
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        model: torch.nn.Module,
        windows: WindowIndex,
        order: WindowOrder,
        noise_std: float,
        optimizer: torch.optim.Optimizer,
        scheduler,
        ema: WeightAverage[LearnedSimulator] | None,
        processes: Processes,
        device: torch.device,
        *,
        seed: int,
        pushforward_steps: int = 0,
        unrolled_loss_steps: int = 0,
        precision: Precision = "float32",
    ):
        self.simulator, self.model = simulator, model
        self.windows, self.order = windows, order
        self.noise_std = noise_std
        self.optimizer, self.scheduler, self.ema = optimizer, scheduler, ema
        self.processes, self.device, self.unrolled_loss_steps = processes, device, unrolled_loss_steps
        self.seed, self.most_pushforward, self.precision = seed, pushforward_steps, precision
        # Copies to a GPU from pinned host memory need not block the host.
        self.pins_memory = is_cuda(device)

    def __call__(self, step: int) -> tuple[Tensor, int]:
        """Optimiser step number ``step`` on this process's windows of it.

        Nothing here waits for the device: the batch and its noise are built on the host and
        copied from pinned memory without blocking when training on a GPU, and the loss stays a
        device tensor (the caller reads it back when it needs it). The graph builder's edge count
        is the one read-back a step needs (``radius_pairs``). Returns the global batch's loss, a
        float64 scalar tensor on the device, and its particle count (both the same on every rank).
        """
        drawn = self.order.draw(step)
        batch = self.windows.batch(drawn.mine)
        particles, setup = [self.windows.num_particles(w) for w in drawn.mine], self.simulator.setup
        noise = step_noise(drawn, particles, (setup.history, setup.dim), self.noise_std, self.seed)
        if self.pins_memory:
            batch, noise = batch.pinned(), noise.pin_memory()
        batch = batch.to(self.device)
        unrolled = self.pushforward_steps(step)
        if unrolled:
            batch = self.pushed_forward(batch, unrolled)
        mask = self.simulator.predicted_mask(batch.particle_type)
        noise = noise.to(self.device, non_blocking=True) * mask[:, None, None]
        loss = self.gradients(batch, noise, mask)
        self.optimizer.step()
        if self.ema is not None:
            self.ema.update(self.simulator)
        self.scheduler.step()
        return loss, sum(self.windows.num_particles(w) for w in drawn.every)

    def gradients(self, batch: ParticleBatch, noise: Tensor, mask: Tensor) -> Tensor:
        """Fresh gradients of the global batch's loss on every rank; returns that loss (float64).

        The loss averages the squared error over the predicted particles of *every* rank's windows (and unrolled
        steps): each rank divides its error sum by the all-reduced count times the world size, which DDP's averaging
        undoes, so W processes of B windows take exactly one process's step with the same W x B windows.
        """
        with autocast(self.precision, self.device):
            prediction, target = self.model(batch, noise, self.unrolled_loss_steps)
        mask = mask.repeat(1 + self.unrolled_loss_steps)
        error_sum = masked_squared_error_sum(prediction.to(target.dtype), target, mask)
        local = torch.stack([error_sum.detach().double(), mask.sum().double()])
        global_error, global_predicted = self.processes.sum(local).unbind()
        predicted = global_predicted.clamp(min=1.0)
        loss = error_sum * self.processes.world_size / predicted.to(error_sum.dtype)
        self.optimizer.zero_grad(set_to_none=True)
        with backward_precision(self.precision, self.device):
            loss.backward()
        return global_error / predicted

    def pushforward_steps(self, step: int) -> int:
        """k of step ``step``'s push-forward, uniform in 0..``pushforward_steps``, the same on every rank."""
        if not self.most_pushforward:
            return 0
        return int(np.random.default_rng([self.seed, 2, step]).integers(0, self.most_pushforward + 1))

    @torch.no_grad()
    def pushed_forward(self, batch: ParticleBatch, steps: int) -> ParticleBatch:
        """``batch`` with its inputs rolled ``steps`` on by the model itself, and the true frames after them as targets.

        No gradient flows through the unrolled steps (the push-forward trick): the model is trained on the inputs
        its own rollouts produce, as it will meet them, at the cost of ``steps`` extra forward passes. Kinematic
        particles follow their true positions.
        """
        assert batch.next_position is not None and batch.ahead is not None  # windows drawn with push-forward steps
        truth = torch.cat([batch.next_position[:, None], batch.ahead], dim=1)
        sequence = batch.position_sequence
        for k in range(steps):
            rolled = self.simulator.predict_next_position(
                replace(batch, position_sequence=sequence), prescribed=truth[:, k]
            )
            sequence = advance_window(sequence, rolled)
        return replace(batch, position_sequence=sequence, next_position=truth[:, steps], ahead=truth[:, steps + 1 :])
