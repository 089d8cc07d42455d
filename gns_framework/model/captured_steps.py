"""Rollout steps replayed from one capture: one launch per step instead of hundreds (issue 45, item 4).

:func:`~gns_framework.model.rollout.rollout_step` on fixed input tensors is captured once
(:class:`~gns_framework.runtime.capture.CapturedStep`: a CUDA graph on CUDA, an emulation
elsewhere); each step copies its window, its step context and the kinematic particles'
next positions into those tensors and replays. The step must not wait for the device:
the graph builder must write into fixed-size buffers (``radius_fixed_capacity``), and the
processor read nothing back (``grid_cnn`` reads its grid's size back: not capturable yet).
When the builder grows its buffers the shapes change, so the rollout calls
:meth:`CapturedSteps.invalidate` and the next step captures afresh.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any

from torch import Tensor

from ..data.batch import ParticleBatch
from ..runtime.capture import CapturedStep, CaptureError


class CapturedSteps:
    """Steps ``(sequence, context, kinematic_next) -> (next_position, continued)`` from a captured step.

    Args:
        step: ``step(current, kinematic_next)``, one rollout step of the batch ``current`` (the rollout's
            ``rollout_step`` with its model, guard and precision bound).
        state: the rollout's first batch, whose window and context each step replaces.
        builder: the model's graph builder, named when the step cannot be captured.

    Shapes: sequence (N, C, d); context (1, F) or None; kinematic_next (K, d) -> (N, d), (N, d),
    fresh tensors each call (the captured outputs are copied: the next replay rewrites them).
    """

    def __init__(self, step: Callable[[ParticleBatch, Tensor], tuple[Tensor, Tensor]], state: ParticleBatch, builder):
        self.step, self.state, self.builder = step, state, builder
        self.captured: CapturedStep | None = None
        self.captures = 0
        self.inputs: tuple[Tensor, Tensor | None, Tensor] | None = None
        self.static_state: ParticleBatch | None = None

    def __call__(self, sequence: Tensor, context: Tensor | None, kinematic_next: Tensor) -> tuple[Tensor, Tensor]:
        if self.captured is None:
            self._capture(sequence, context, kinematic_next)
        assert self.captured is not None and self.inputs is not None
        static_sequence, static_context, static_kinematic = self.inputs
        static_sequence.copy_(sequence)
        if static_context is not None and context is not None:
            static_context.copy_(context)
        static_kinematic.copy_(kinematic_next)
        next_position, continued = self.captured()
        return next_position.clone(), continued.clone()

    def rebound(self, state: ParticleBatch) -> CapturedSteps:
        """These steps for another batch of the same shapes (the next batch of a capacity class).

        Its fields (types, examples, properties, walls) are copied into the tensors the capture
        reads, so the capture is replayed, not made again. The step function is the first
        batch's: what it binds besides the batch (the model, its guard, the kinematic rows)
        must be the same objects, rewritten in place where they change.
        """
        if self.static_state is not None:
            examples = self.static_state.num_examples
            if state.num_examples != examples:
                raise ValueError(f"a batch of {state.num_examples} examples cannot replay a capture of {examples}")
            for name, static, value in _tensor_fields(self.static_state, state):
                if static.shape != value.shape:
                    shapes = f"{tuple(value.shape)} cannot replay a capture of {tuple(static.shape)}"
                    raise ValueError(f"a batch's {name} of shape {shapes}")
                static.copy_(value)
        self.state = state
        return self

    def invalidate(self) -> None:
        """Capture again at the next step (the graph builder's buffers changed size)."""
        self.captured = None

    def _capture(self, sequence: Tensor, context: Tensor | None, kinematic_next: Tensor) -> None:
        static_sequence = sequence.clone()
        static_context = None if context is None else context.clone()
        static_kinematic = kinematic_next.clone()
        self.inputs = (static_sequence, static_context, static_kinematic)
        own: dict[str, Any] = {name: value.clone() for name, value, _ in _tensor_fields(self.state, self.state)}
        self.static_state = replace(self.state, **own)
        current = replace(self.static_state, position_sequence=static_sequence, context=static_context)
        try:
            self.captured = CapturedStep(lambda: self.step(current, static_kinematic), sequence.device)
        except (CaptureError, RuntimeError) as error:
            # A radius search of exact size reads its edge count back: the fixed-capacity one does not.
            waits = self.builder.joins_within_radius and not self.builder.fixed_capacity
            hint = f"; the graph builder {self.builder.name!r} waits for the device: use radius_fixed_capacity"
            hint = hint if waits else ""
            raise CaptureError(f"this model's rollout step cannot be captured: {error}{hint}") from error
        self.captures += 1


def _tensor_fields(captured: ParticleBatch, batch: ParticleBatch) -> list[tuple[str, Tensor, Tensor]]:
    """``(name, captured tensor, batch's tensor)`` of every tensor field both batches have."""
    pairs = []
    for field in fields(captured):
        static, value = getattr(captured, field.name), getattr(batch, field.name)
        if isinstance(static, Tensor) and isinstance(value, Tensor):
            pairs.append((field.name, static, value))
        elif isinstance(static, Tensor) != isinstance(value, Tensor):
            raise ValueError(f"a batch without {field.name} cannot replay a capture with it, or the other way")
    return pairs
