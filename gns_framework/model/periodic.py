"""Periodic domains: wrapping positions into the box and minimum-image differences.

In a dimension that wraps around, stored positions jump by the box length L when a
particle crosses a face. Every difference of positions (velocities, accelerations,
edge displacements) is therefore taken as the minimum image: the representative
of ``b - a`` modulo L that lies in ``[-L/2, L/2)``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..contracts import ModelSetup
from ..runtime.host_sync import PerDevice


class PeriodicBox:
    """The wrap-around geometry of a scene's periodic dimensions.

    Args:
        scene: its ``bounds`` give the box; ``periodic_dims`` the wrapping dimensions.
    """

    def __init__(self, scene: ModelSetup):
        self.dims = list(scene.periodic_dims)
        bounds = torch.tensor(scene.bounds, dtype=torch.float64)
        self.lower = bounds[self.dims, 0]
        self.length = bounds[self.dims, 1] - bounds[self.dims, 0]
        self._constants = PerDevice(self._make_constants)

    @property
    def active(self) -> bool:
        return bool(self.dims)

    def constants(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(dims, lower, length)`` on ``like``'s device, the last two in its dtype; made once per device and dtype."""
        return self._constants(like)

    def _make_constants(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        dims = torch.tensor(self.dims, dtype=torch.long, device=like.device)
        return dims, self.lower.to(like), self.length.to(like)

    def minimum_image(self, difference: Tensor) -> Tensor:
        """(..., d) differences of positions -> the same with periodic components in [-L/2, L/2)."""
        if not self.active:
            return difference
        dims, _, length = self.constants(difference)
        part = difference.index_select(-1, dims)
        return difference.index_copy(-1, dims, part - length * torch.floor(part / length + 0.5))

    def wrap(self, position: Tensor) -> Tensor:
        """(..., d) positions -> the same with periodic components in [lower, lower + L)."""
        if not self.active:
            return position
        dims, lower, length = self.constants(position)
        inside = lower + torch.remainder(position.index_select(-1, dims) - lower, length)
        # remainder(-tiny, L) rounds to L itself: fold that onto the lower face.
        return position.index_copy(-1, dims, torch.where(inside >= lower + length, lower, inside))

    def unwrap_history(self, position_sequence: Tensor) -> Tensor:
        """(N, C, d) stored history -> a continuous one that ends at the same (wrapped) frame.

        Earlier frames are rebuilt backwards from the last with minimum-image
        steps, so finite differences of the result are the true displacements.
        """
        if not self.active:
            return position_sequence
        steps = self.minimum_image(position_sequence[:, 1:] - position_sequence[:, :-1])
        # Positions before the last, as the last minus the steps taken since.
        since = torch.flip(torch.cumsum(torch.flip(steps, [1]), 1), [1])
        last = position_sequence[:, -1:]
        return torch.cat([last - since, last], dim=1)

    def unwrap_next(self, last_position: Tensor, next_position: Tensor) -> Tensor:
        """(N, d) stored next frame -> its continuation of ``last_position`` (minimum image)."""
        return last_position + self.minimum_image(next_position - last_position)
