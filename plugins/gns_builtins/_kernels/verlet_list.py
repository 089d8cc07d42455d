"""Neighbour lists with a skin (Verlet lists): the radius search redone only when particles have moved far enough.

Molecular dynamics codes search once for pairs closer than R + s (the skin s) and,
at every step, keep those of them closer than R. While no particle has moved more than
s / 2 since that search, every pair now closer than R was closer than R + s then
(|d_then| <= |d_now| + |u_i| + |u_j| < R + s), so the kept pairs are exactly the
radius graph: the same pairs, compared in the same arithmetic, in the same
(receiver, sender) order. In a rollout the search is then skipped for as long as the
sand moves slowly, which is most of a collapse once the pile has formed.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .cell_list import radius_pairs, squared_distance

REBUILD_FRACTION = 0.45
"""Displacement, as a fraction of the skin, past which the list is searched again: below the exact
bound of one half, so that the float rounding of the search's own comparison never drops a pair."""


class VerletList:
    """The radius graph of consecutive frames of one batch, searched again only when needed.

    Args:
        radius: connectivity radius R (> 0).
        skin: s, in the units of R (> 0): candidates are the pairs closer than R + s.

    ``searches`` counts the radius searches made, for benchmarks and tests.
    """

    def __init__(self, radius: float, skin: float):
        self.radius, self.skin = radius, skin
        self.searches = 0
        self._batch: Tensor | None = None
        self._searched_at: Tensor | None = None
        self._candidates: tuple[Tensor, Tensor] | None = None

    def pairs(self, position: Tensor, batch: Tensor) -> tuple[Tensor, Tensor]:
        """Senders and receivers (E,) of the pairs of one example closer than R, as ``radius_pairs`` gives them."""
        if self._stale(position, batch):
            self._candidates = radius_pairs(position, batch, self.radius + self.skin)
            self._searched_at, self._batch = position.detach().clone(), batch
            self.searches += 1
        assert self._candidates is not None
        senders, receivers = self._candidates
        r2 = torch.full((), self.radius * self.radius, dtype=position.dtype, device=position.device)
        kept = (squared_distance(position[receivers], position[senders]) < r2).nonzero().squeeze(1)
        return senders[kept], receivers[kept]

    def _stale(self, position: Tensor, batch: Tensor) -> bool:
        """Whether the candidates belong to other particles, or some particle has moved too far since the search."""
        searched = self._searched_at
        if searched is None or self._batch is None or position.shape[0] == 0:
            return True
        if searched.shape != position.shape or searched.device != position.device:
            return True
        if batch is not self._batch and not torch.equal(batch, self._batch):
            return True
        moved = squared_distance(position.detach().to(torch.float64), searched.to(torch.float64))
        limit = REBUILD_FRACTION * self.skin
        return bool(moved.max() > limit * limit)
