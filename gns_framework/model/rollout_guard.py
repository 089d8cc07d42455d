"""Guarding rollouts: non-finite positions and particles lost beyond the walls are caught at the step they occur.

A learned simulator that diverges produces NaN, Inf or particles flung far out of
the domain; continuing feeds them back into the model and the rollout file would
hold them without a word. The guard checks every predicted frame and either stops
(:class:`~gns_framework.errors.RolloutDiverged`, naming the step, the particles and
the cause) or, when the recipe says ``rollout.guard.on_violation: clamp``, puts the
particles back and records what it did.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..config.recipe import RolloutGuardSpec
from ..contracts import ModelSetup
from ..errors import RolloutDiverged
from ..runtime.host_sync import PerDevice

SHOWN_PARTICLES = 5
"""Particle indices listed in a message before the count takes over."""


@dataclass(frozen=True)
class GuardViolation:
    """What one check found: the step (0-based, frame ``step + C``), the particles and the cause.

    ``escaped``: the particles left the domain (under ``clamp``, a wall held them); else they were non-finite.
    ``excess``: for escaped particles, how far the farthest of them was beyond a wall (length units).
    """

    step: int
    frame: int
    particles: np.ndarray
    cause: str
    escaped: bool = False
    excess: float = 0.0

    def describe(self) -> str:
        shown = ", ".join(str(int(i)) for i in self.particles[:SHOWN_PARTICLES])
        more = f", ... ({len(self.particles)} in all)" if len(self.particles) > SHOWN_PARTICLES else ""
        return f"step {self.step} (frame {self.frame}): {len(self.particles)} particle(s) [{shown}{more}] {self.cause}"


class RolloutGuard:
    """Checks each predicted frame of a rollout.

    Args:
        scene: bounds (the walls) and periodic dimensions (no walls there: wrapped positions never leave).
        margin: distance (dataset length units) a particle may pass a wall; None: no domain check, only
            non-finite positions are caught (an untrained or early model may fling particles far out,
            and that is a result to evaluate, not an error).
        on_violation: ``stop`` raises RolloutDiverged; ``clamp`` replaces non-finite positions by the
            particle's previous position and puts escaped particles back onto the wall they passed.
    """

    def __init__(self, scene: ModelSetup, margin: float | None = None, on_violation: str = "stop"):
        if on_violation not in ("stop", "clamp"):
            raise ValueError(f"on_violation must be 'stop' or 'clamp', got {on_violation!r}")
        bounds = torch.tensor(scene.bounds, dtype=torch.float64)
        self.walled = [k for k in range(scene.dim) if k not in scene.periodic_dims]
        self.lower = bounds[self.walled, 0]
        self.upper = bounds[self.walled, 1]
        self.margin = math.inf if margin is None else float(margin)
        self.on_violation = on_violation
        self.history = scene.history
        self._walled = PerDevice(self._make_walled)

    @classmethod
    def from_spec(cls, scene: ModelSetup, spec: RolloutGuardSpec) -> RolloutGuard:
        return cls(scene, spec.margin, spec.on_violation)

    def with_bounds(self, bounds) -> RolloutGuard:
        """This guard for a trajectory with its own domain: (d, 2) lower and upper walls, or (N, d, 2) per particle
        (scenes rolled out as one batch, each in its own box)."""
        guard = copy.copy(self)
        walls = torch.as_tensor(np.asarray(bounds), dtype=torch.float64)
        guard.lower = walls[..., self.walled, 0]
        guard.upper = walls[..., self.walled, 1]
        guard._walled = PerDevice(guard._make_walled)
        return guard

    def rewrite_bounds(self, bounds) -> None:
        """Other walls of the same shape as :meth:`with_bounds` gave, written in place: on the host and on every
        device this guard has met, so that a captured step reading them replays with these (the next batch of a
        capacity class, :mod:`.capacity_classes`)."""
        walls = torch.as_tensor(np.asarray(bounds), dtype=torch.float64)
        lower, upper = walls[..., self.walled, 0], walls[..., self.walled, 1]
        if lower.shape != self.lower.shape:
            raise ValueError(
                f"walls of shape {tuple(lower.shape)} cannot replace walls of shape {tuple(self.lower.shape)}"
            )
        self.lower.copy_(lower)
        self.upper.copy_(upper)
        for _dims, on_device_lower, on_device_upper in self._walled.made.values():
            on_device_lower.copy_(lower)
            on_device_upper.copy_(upper)

    def check(
        self, step: int, position: Tensor, previous: Tensor, trajectory: str = "", ids: Tensor | None = None
    ) -> tuple[Tensor, list[GuardViolation]]:
        """Check the predicted frame ``position`` (N, d); ``previous`` (N, d) is the frame before it.

        Returns the frame to continue from (``position`` itself when nothing was wrong)
        and the violations found (empty when none). Raises RolloutDiverged under ``stop``.
        ``ids`` (N,): the particles' numbers in the scene, when ``position`` holds some of them
        (a process's piece); reports name those. Default: the rows' own indices.
        """
        non_finite = ~torch.isfinite(position).all(dim=-1)
        excess = self._beyond_walls(position)
        # NaN compares False: a non-finite particle is reported once, as non-finite.
        escaped = (excess > self.margin) & ~non_finite
        if not bool(non_finite.any() or escaped.any()):
            return position, []
        frame = step + self.history
        violations = []
        number = None if ids is None else ids.cpu().numpy()
        named = (lambda rows: rows) if number is None else (lambda rows: np.sort(number[rows]))
        if non_finite.any():
            violations.append(
                GuardViolation(step, frame, named(_indices(non_finite)), "have non-finite positions (NaN or Inf)")
            )
        if escaped.any():
            farthest = int(torch.argmax(torch.where(escaped, excess, torch.zeros_like(excess))))
            beyond, farthest_id = float(excess[farthest]), farthest if number is None else int(number[farthest])
            cause = (
                f"left the domain by more than the margin {self.margin:g} "
                f"(farthest: particle {farthest_id}, {beyond:.4g} beyond a wall)"
            )
            violations.append(GuardViolation(step, frame, named(_indices(escaped)), cause, True, beyond))
        if self.on_violation == "stop":
            first = violations[0]
            where = f"rollout of trajectory {trajectory!r}" if trajectory else "rollout"
            raise RolloutDiverged(
                f"{where} stopped at "
                + "; ".join(v.describe() for v in violations)
                + ". Nothing was written for this trajectory; set rollout.guard.on_violation: clamp to continue "
                "with the particles put back",
                trajectory=trajectory,
                step=step,
                particles=first.particles.tolist(),
                cause=first.cause,
            )
        return self._clamped(position, previous, non_finite, escaped), violations

    def continued(self, position: Tensor, previous: Tensor) -> Tensor:
        """The frame a rollout continues from, with no read-back from the device.

        Under ``clamp`` exactly what :meth:`check` returns. Under ``stop`` non-finite
        positions are replaced by the previous ones, so that the steps run before the
        (deferred) :meth:`check` of this frame raises never feed NaN to the graph builder.
        """
        non_finite = ~torch.isfinite(position).all(dim=-1)
        position = torch.where(non_finite[:, None], previous, position)
        if self.on_violation == "stop" or not self.walled:
            return position
        escaped = (self._beyond_walls(position) > self.margin) & ~non_finite
        return self._onto_walls(position, escaped)

    def _make_walled(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(walled dims, lower, upper)`` on ``like``'s device and dtype (kept per device and dtype by ``_walled``)."""
        dims = torch.tensor(self.walled, dtype=torch.long, device=like.device)
        return dims, self.lower.to(like), self.upper.to(like)

    def _beyond_walls(self, position: Tensor) -> Tensor:
        """(N,) largest distance by which a particle is outside a wall (0 inside)."""
        if not self.walled:
            return position.new_zeros(position.shape[0])
        dims, lower, upper = self._walled(position)
        walled = position.index_select(1, dims)
        outside = torch.maximum(lower - walled, walled - upper).clamp(min=0)
        return outside.max(dim=-1).values

    def _clamped(self, position: Tensor, previous: Tensor, non_finite: Tensor, escaped: Tensor) -> Tensor:
        position = torch.where(non_finite[:, None], previous, position)
        return self._onto_walls(position, escaped) if escaped.any() else position

    def _onto_walls(self, position: Tensor, escaped: Tensor) -> Tensor:
        """``position`` with the ``escaped`` particles put back onto the walls they passed."""
        dims, lower, upper = self._walled(position)
        walled = position.index_select(1, dims)
        onto_walls = torch.minimum(torch.maximum(walled, lower), upper)
        return position.index_copy(1, dims, torch.where(escaped[:, None], onto_walls, walled))


def _indices(mask: Tensor) -> np.ndarray:
    return mask.nonzero()[:, 0].cpu().numpy()


def held_particles(violations) -> int:
    """How many particles a wall held (put back after they left the domain) in one rollout's ``violations``."""
    held = [v.particles for v in violations if v.escaped]
    return int(np.unique(np.concatenate(held)).size) if held else 0


def merged_violations(found: Iterable[GuardViolation]) -> list[GuardViolation]:
    """Violations found on the pieces of one scene (one process's particles each) as one check of the whole
    frame reports them: per step, the non-finite particles, then the escaped ones with the farthest escape's
    cause, their numbers sorted."""
    groups: dict[tuple[int, bool], list[GuardViolation]] = {}
    for violation in found:
        groups.setdefault((violation.step, violation.escaped), []).append(violation)
    return [
        dataclasses.replace(
            max(parts, key=lambda v: v.excess), particles=np.sort(np.concatenate([v.particles for v in parts]))
        )
        for _, parts in sorted(groups.items())
    ]
