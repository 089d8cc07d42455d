"""The training step captured at a fixed size: two replays per step instead of a thousand launches (issue 45, item 4).

A training batch is a few windows of scenes of different particle counts, so its shapes
change every step and a captured step (a CUDA graph) would be captured again each time.
Here each batch is padded to a capacity class (:func:`~gns_framework.model.capacity_classes.
particle_capacity`: the particle count rounded up by at most 25 %), with one example more
holding the padding rows, and each class keeps one capture of the step's gradients.

What a padding row must not do, and how it is kept from it:

- join an edge: the graph builder sees it at a NaN position, and builders join such a
  particle to no one (the contract of :meth:`GraphBuilder.build`);
- make anything NaN: everything else sees a copy of the batch's last row, so its
  features, latents and predictions are finite. A NaN row would be harmless forward
  (its loss is masked out) but not backward: a weight's gradient multiplies every row's
  input by that row's (zero) output gradient, and NaN times zero is NaN;
- count in the loss: it is masked out with the kinematic particles, so the loss, its
  gradients and the update are those of the unpadded batch (up to the order of float sums).

A step is two replays. The first computes the gradients into tensors that stay in place
(each replay zeroes and refills them), then the host reads once whether the graph
builder's buffers held every edge (``GraphBuilder.overflowed``); if not they grow, the
class is captured again and the batch redone, so no update is ever taken from an
incomplete graph. The second replay is the update: fused Adam with a learning rate held
in a tensor (the schedule writes it in place) and the weight average. That one read-back
per step is the price of an exact update; a rollout step needs none (it checks every
few steps and redoes them).

The first step of a process runs eagerly (it makes the optimiser's state and the weight
average's first copy); every capture runs its warm-up on a copy of the training state,
which is put back afterwards, so captured training takes the same steps as eager
training. One process only, with ``radius_fixed_capacity`` (a builder of exact size reads
its edge count back) and a processor that reads nothing back.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields, replace
from typing import Any, TypeVar

import torch
from torch import Tensor

from ..contracts import Graph, GraphBuilder
from ..data.batch import ParticleBatch
from ..model.capacity_classes import class_key, particle_capacity
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_squared_error_sum
from ..model.noise import step_noise
from ..runtime.capture import CapturedStep, CaptureError
from ..runtime.precision import autocast, backward_precision
from .step import TrainingStep

T = TypeVar("T")

PER_EXAMPLE = ("context", "bounds", "walls")
"""ParticleBatch fields with a row per example (the padding example repeats the last one's)."""


def padded_windows(batch: ParticleBatch, capacity: int) -> tuple[ParticleBatch, Tensor]:
    """``batch`` with one example more, of ``capacity - N`` rows copying its last row, and the (capacity,) padding mask.

    Shapes: per-particle fields (N, ...) -> (capacity, ...); per-example ones (B, ...) -> (B + 1, ...).
    """
    n = batch.num_particles
    if capacity < n:
        raise ValueError(f"a batch of {n} particles exceeds a class of {capacity}")
    extra = capacity - n
    grown: dict[str, Any] = {}
    for field in fields(batch):
        value = getattr(batch, field.name)
        if not isinstance(value, Tensor) or field.name == "batch":
            continue
        if field.name in PER_EXAMPLE:
            grown[field.name] = torch.cat([value, value[-1:]])
        else:
            grown[field.name] = torch.cat([value, value[-1:].expand(extra, *value.shape[1:])])
    examples = torch.full((extra,), batch.num_examples, dtype=batch.batch.dtype)
    padded = replace(batch, **grown, batch=torch.cat([batch.batch, examples]), num_examples=batch.num_examples + 1)
    return padded, torch.arange(capacity) >= n


class _PaddingLeftOut(GraphBuilder):
    """A model's graph builder that sees the padding rows at NaN positions (joined to no one)."""

    name = "padding_left_out"

    def __init__(self, builder: GraphBuilder, padding: Tensor):
        super().__init__(builder.params, builder.setup)
        self.builder, self.padding = builder, padding

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        hidden = torch.where(self.padding[:, None], torch.full_like(position, float("nan")), position)
        graph = self.builder.build(hidden, batch, num_examples)
        # A fixed-capacity graph's padding edges join its sink node, the last row: a padding row, here at NaN.
        return replace(graph, displacement=graph.displacement.nan_to_num(0.0))


@contextmanager
def padding_left_out(simulator: LearnedSimulator, padding: Tensor) -> Iterator[None]:
    """Within, ``simulator`` builds its graphs without the rows where ``padding`` (N,) is True."""
    builder = simulator.graph_builder
    simulator.graph_builder = _PaddingLeftOut(builder, padding)
    try:
        yield
    finally:
        simulator.graph_builder = builder


@dataclass
class _Class:
    """One capacity class: the tensors its capture reads and the capture."""

    key: Hashable
    batch: ParticleBatch
    noise: Tensor
    padding: Tensor
    pushforward: int
    gradients: CapturedStep[Tensor] | None = None
    steps: int = 0


class CapturedTrainingStep:
    """``step(step_number)`` as :class:`TrainingStep` does it, replayed from captures (see the module's docstring).

    Args:
        step: the run's eager training step (its model, data, Adam and schedule). Adam is made capturable
            (:func:`make_capturable`) at the first step, after any resume.

    ``captures`` counts the captures of gradient steps, ``eager_steps`` the steps run eagerly, for tests.
    """

    def __init__(self, step: TrainingStep):
        if step.processes.world_size > 1:
            raise CaptureError("training.capture_step: one process only (a captured step cannot all-reduce yet)")
        self.eager = step
        self.simulator = step.simulator
        self.classes: dict[Hashable, _Class] = {}
        self.update: CapturedStep[None] | None = None
        self.captures = self.eager_steps = 0
        self._grads: list[Tensor] = []

    def __call__(self, step: int) -> tuple[Tensor, int]:
        """Optimiser step number ``step``: the global batch's loss (float64, on the device) and its particle count."""
        eager = self.eager
        if not self.eager_steps:
            # Makes the optimiser's state and the weight average's first copy, which a replay cannot.
            make_capturable(eager.optimizer)
            self.eager_steps += 1
            loss, particles = eager(step)
            self._grads = self._static_gradients()
            return loss, particles
        drawn = eager.order.draw(step)
        batch = eager.windows.batch(drawn.mine)
        counts, setup = [eager.windows.num_particles(w) for w in drawn.mine], self.simulator.setup
        noise = step_noise(drawn, counts, (setup.history, setup.dim), eager.noise_std, eager.seed)
        padded, padding = padded_windows(batch, particle_capacity(batch.num_particles))
        noise = torch.cat([noise, noise.new_zeros(len(padding) - len(noise), *noise.shape[1:])])
        if eager.pins_memory:  # copies to a GPU from pinned memory need not block the host
            padded, noise, padding = padded.pinned(), noise.pin_memory(), padding.pin_memory()
        unrolled = eager.pushforward_steps(step)
        kept = self._class(padded, noise, padding, unrolled)
        loss = self._gradients(kept)
        if self.update is None:
            self.update = self._capture_keeping_state(self._update)
        self.update()
        eager.scheduler.step()
        return loss, sum(eager.windows.num_particles(w) for w in drawn.every)

    def _class(self, padded: ParticleBatch, noise: Tensor, padding: Tensor, unrolled: int) -> _Class:
        """The class of this padded batch, its tensors rewritten with it (made, on its device, at its first batch)."""
        device = self.eager.device
        key = (*class_key(padded, self.eager.precision), unrolled)
        kept = self.classes.get(key)
        if kept is None:
            on_device = padded.to(device)
            kept = self.classes[key] = _Class(key, on_device, noise.to(device), padding.to(device), unrolled)
            return kept
        for field in fields(padded):
            value = getattr(padded, field.name)
            if isinstance(value, Tensor):
                getattr(kept.batch, field.name).copy_(value, non_blocking=True)
        kept.noise.copy_(noise, non_blocking=True)
        kept.padding.copy_(padding, non_blocking=True)
        return kept

    def _gradients(self, kept: _Class) -> Tensor:
        """Replay the class's gradient step until its graphs held every edge; returns the loss (a fresh tensor)."""
        builder = self.simulator.graph_builder
        builder.checks_deferred = True
        try:
            with builder.buffers(kept.key):
                while True:
                    if kept.gradients is None:
                        kept.gradients = self._capture(kept)
                    loss = kept.gradients()
                    if not builder.overflowed():
                        break
                    kept.gradients = None  # the buffers grew: other shapes, another capture
        finally:
            builder.checks_deferred = False
        kept.steps += 1
        return loss.clone()

    def _capture(self, kept: _Class) -> CapturedStep[Tensor]:
        eager, simulator = self.eager, self.simulator

        def gradients() -> Tensor:
            torch._foreach_zero_(self._grads)
            batch = eager.pushed_forward(kept.batch, kept.pushforward) if kept.pushforward else kept.batch
            mask = simulator.predicted_mask(batch.particle_type) & ~kept.padding
            with autocast(eager.precision, eager.device):
                prediction, target = eager.model(batch, kept.noise * mask[:, None, None])
            error_sum = masked_squared_error_sum(prediction.to(target.dtype), target, mask)
            predicted = mask.sum().double().clamp(min=1.0)
            with backward_precision(eager.precision, eager.device):
                (error_sum / predicted.to(error_sum.dtype)).backward()
            return error_sum.detach().double() / predicted

        try:
            with padding_left_out(simulator, kept.padding):
                captured = self._capture_keeping_state(gradients)
        except (CaptureError, RuntimeError) as error:
            builder = simulator.graph_builder
            hint = "" if builder.fixed_capacity else f"; the graph builder {builder.name!r} waits for the device"
            raise CaptureError(
                f"training.capture_step: this model's training step cannot be captured: {error}{hint}"
            ) from error
        self.captures += 1
        return captured

    def _update(self) -> None:
        self.eager.optimizer.step()
        if self.eager.ema is not None:
            self.eager.ema.update(self.simulator)

    def _static_gradients(self) -> list[Tensor]:
        """Every parameter's gradient as a tensor kept in place: the gradient replays fill it, the update reads it."""
        grads = []
        for parameter in self.simulator.parameters():
            if parameter.grad is None:
                parameter.grad = torch.zeros_like(parameter)
            grads.append(parameter.grad)
        return grads

    def _capture_keeping_state(self, function: Callable[[], T]) -> CapturedStep[T]:
        """``function`` captured, with the weights, optimiser state and weight average it changed while
        warming up (and, emulated, capturing) put back as they were."""
        state = self._training_state()
        kept = [t.detach().clone() for t in state]
        try:
            return CapturedStep(function, self.eager.device)
        finally:
            with torch.no_grad():
                for tensor, value in zip(state, kept, strict=True):
                    tensor.copy_(value)

    def _training_state(self) -> list[Tensor]:
        state: list[Tensor] = list(self.simulator.parameters())
        for per_parameter in self.eager.optimizer.state.values():
            state.extend(v for v in per_parameter.values() if isinstance(v, Tensor))
        ema = self.eager.ema
        if ema is not None:
            state.extend(ema.tensors())
        return state


def make_capturable(optimizer: torch.optim.Optimizer) -> None:
    """Adam set up for an update captured once and replayed, whatever a loaded checkpoint's groups said.

    Fused (one kernel reading its step counts on the device, no read-back), capturable, the
    learning rate a tensor on the parameters' device (the schedule then writes it in place,
    which a replay reads) and every step count there too.
    """
    for group in optimizer.param_groups:
        device = group["params"][0].device
        lr = group["lr"]
        group["lr"] = lr.to(device) if isinstance(lr, torch.Tensor) else torch.tensor(float(lr), device=device)
        group.update(fused=True, capturable=True, foreach=None)
        for parameter in group["params"]:
            state = optimizer.state.get(parameter)
            if state and "step" in state:
                state["step"] = state["step"].to(device=device, dtype=torch.float32)
